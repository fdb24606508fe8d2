"""The analysis report's page: one self-contained index.html that a person reads from top to bottom.

Order of the page: the verdict (chosen model, chi2/dof) and, for a run that did not finish, a warning
banner; what was analysed; the chosen model's parameters with std errors and meanings; the selection
table and its reason; every warning raised while loading and fitting; the figures with one-line
captions; the coverage of the BRDF domain. Inline CSS only and no scripts, so the page works from a
file system, an archive or a mail attachment; figures are linked relatively (figures/NAME.png, the SVG
behind each). Every piece of text from data or files goes through html.escape.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from html import escape
from pathlib import Path
from typing import TYPE_CHECKING

from acquisition.files.atomic import write_atomic
from analysis.parameters import correlation, parameter_status, undetermined_text
from analysis.report.truth import MAX_THETA_DEG, compare_truth
from analysis.result import Analysis, noise_words
from model.fit.solve import FitResult
from model.version import gonio_version

if TYPE_CHECKING:  # the page reads the written figures' paths and captions; it draws nothing (no matplotlib)
    from analysis.report.files import Figures

#: What each fitted field means; all BRDF model parameters are dimensionless.
MEANINGS = {
    "rho_d": "diffuse albedo (dimensionless, 0..1)",
    "rho_s": "specular albedo (dimensionless, 0..1)",
    "alpha": "microfacet roughness alpha (dimensionless)",
    "alpha_x": "Ward slope along x (dimensionless)",
    "alpha_y": "Ward slope along y (dimensionless)",
    "eta": "refractive index, real part (dimensionless)",
    "k": "extinction coefficient (dimensionless)",
    "f0": "reflectance at normal incidence (dimensionless, 0..1)",
    "n": "Blinn-Phong exponent (dimensionless)",
}
_CHANNEL = re.compile(r"^(?P<field>.+)_(?P<ch>[rgb]|\d+)$")

CSS = """
body { font: 15px/1.45 system-ui, sans-serif; max-width: 1180px; margin: 1.5em auto; padding: 0 1em; color: #222; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; }
h2 { font-size: 1.15em; margin-top: 1.8em; border-bottom: 1px solid #ddd; }
.verdict { font-size: 1.1em; background: #eef6ee; padding: 0.6em 0.9em; border-left: 4px solid #009E73; }
.warn { background: #fff4e0; padding: 0.6em 0.9em; border-left: 4px solid #D55E00; font-weight: 600; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.93em; }
.scroll { max-width: 100%; overflow-x: auto; }
.scroll table { margin: 0; }
@media (max-width: 900px) { body { font-size: 14px; } th, td { padding: 0.2em 0.4em; } }
th, td { padding: 0.25em 0.7em; border-bottom: 1px solid #e4e4e4; text-align: left; vertical-align: top; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.rho { text-align: right; font-variant-numeric: tabular-nums; min-width: 3.2em; }
tr.chosen td { font-weight: 700; background: #f3f8ff; }
tr.flag td { background: #fff4e0; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { color: #444; font-size: 0.93em; } .muted { color: #777; font-size: 0.88em; }
"""


def _num(v: float, fmt: str = ".4g") -> str:
    return format(v, fmt) if math.isfinite(v) else ("unconstrained" if math.isinf(v) else "n/a")


def _meaning(label: str) -> str:
    if label in MEANINGS:
        return MEANINGS[label]
    m = _CHANNEL.match(label)
    if m and m["field"] in MEANINGS:
        return f"{MEANINGS[m['field']]}, channel {m['ch']}"
    return "(dimensionless)"


def _table(header: list[str], rows: list[tuple[list[str], str]]) -> str:
    """An HTML table from already escaped cells; each row carries a class ("" for none); numbers right-aligned."""
    head = "".join(f"<th>{h}</th>" for h in header)
    body = []
    for cells, cls in rows:
        tds = "".join(f'<td class="num">{c}</td>' if _looks_numeric(c) else f"<td>{c}</td>" for c in cells)
        body.append(f'<tr class="{cls}">{tds}</tr>' if cls else f"<tr>{tds}</tr>")
    # Wide tables scroll inside their own box instead of pushing columns off a narrow page.
    return f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table></div>'


def _looks_numeric(cell: str) -> bool:
    return bool(re.fullmatch(r"[-+0-9.e ±]+|unconstrained|n/a", cell))


def _source(a: Analysis) -> str:
    s = a.source
    what = {"run": "run directory", "adaptive": "adaptive sweep", "table": "samples table"}.get(s.kind, "MERL table")
    rows: list[tuple[str, str]] = [("source", f"{what} {s.path}")]
    # The run's [metadata] (sample, operator, notes and the lab's own keys) heads the page as it was written.
    rows += [(k, ", ".join(map(str, v)) if isinstance(v, list) else str(v)) for k, v in s.metadata]
    if s.kind in ("run", "adaptive"):
        rows += [
            ("run status", s.state + (f" ({s.stop_reason})" if s.stop_reason else "")),
            ("points", f"{s.measured} measured of {s.planned} planned; {s.unreachable} unreachable (not planned)"),
            ("saturated points", f"{s.lower_bound} lower bounds (one-sided: the fit may not lie below)"),
            ("sweep", f"{s.sweep_name} ({s.sweep_kind})"),
            ("rig", str(s.rig_name)),
        ]  # fmt: skip
        if s.material:
            rows.append(("simulated material", s.material))
    elif s.kind == "table":
        rows.append(("samples", f"{s.measured} rows of the table"))
    else:
        rows.append(("samples", f"{s.measured} random bins (std errors assumed)"))
    if a.references:
        rows.append(("drawn for comparison", "; ".join(r.label for r in a.references)))
    n_lower = int(a.samples.lower_bound.sum())
    rows.append(("samples fitted", f"{a.samples.n} ({n_lower} of them lower bounds, fitted as one-sided constraints)"))
    rows += [("note", n) for n in s.notes]
    rows.append(("fit", f"loss {a.loss}, {a.starts} starts, chosen by {a.selection.criterion.upper()}"))
    return "<table>" + "".join(f"<tr><th>{escape(k)}</th><td>{escape(v)}</td></tr>" for k, v in rows) + "</table>"


def _parameters(r: FitResult, a: Analysis) -> str:
    status = parameter_status(r, a.spec(r.spec), a.samples.channels)
    rows = [([escape(p.name), escape(p.value_text()), escape(p.note() or "yes"), escape(_meaning(p.name))],
             "" if p.determined and p.bound is None else "flag") for p in status]  # fmt: skip
    fixed = ", ".join(f"{k} = {v}" for k, v in a.spec(r.spec).fixed.items())
    head = f"<p><b>{escape(r.spec)}</b>: model class <code>{escape(type(r.model).__name__)}</code>"
    head += f"; held fixed: {escape(fixed)}</p>" if fixed else "</p>"
    problem = undetermined_text(status)
    warn = f'<p class="warn">{escape(problem)} (see the table).</p>' if problem else ""
    table = _table(["parameter", "value ± std error", "pinned down by the data?", "meaning (units)"], rows)
    return head + warn + table + _correlations(r)


def _correlations(r: FitResult) -> str:
    """The correlation matrix as a table shaded by |rho|, and where the covariance lives."""
    if r.n_params < 2:
        return ""
    rho = correlation(r.covariance)
    head = "".join(f"<th>{escape(n)}</th>" for n in r.names)
    body = []
    for i, name in enumerate(r.names):
        cells = []
        for j in range(r.n_params):
            v = rho[i, j]
            if not math.isfinite(v):
                cells.append('<td class="rho">n/a</td>')
                continue
            # Shade strong correlations: blue for positive, red for negative, by |rho|.
            w = abs(v) if i != j else 0.0
            colour = f"rgba({'0,114,178' if v > 0 else '213,94,0'},{0.55 * w * w:.2f})"
            cells.append(f'<td class="rho" style="background:{colour}">{v:+.2f}</td>')
        body.append(f"<tr><th>{escape(name)}</th>{''.join(cells)}</tr>")
    note = ("<p>Correlations of the fitted parameters (from the covariance in fit.json, native units; "
            "|ρ| near 1: the data fix a combination of the two, not each alone).</p>")  # fmt: skip
    return (f'{note}<div class="scroll"><table class="corr"><thead><tr><th></th>{head}</tr></thead>'
            f"<tbody>{''.join(body)}</tbody></table></div>")


def _selection(a: Analysis) -> str:
    sel = a.selection
    crit = sel.criterion.upper()
    best = min(c.criterion(sel.criterion) for c in sel.candidates)
    rows = []
    for c in sel.candidates:
        if c.result is None:
            rows.append(([escape(c.name), str(c.n_params), f"not fitted: {escape(str(c.error))}", "", "", "", "", "",
                          ""], ""))  # fmt: skip
            continue
        r = c.result
        rows.append(([escape(c.name) + (" (chosen)" if r is sel.chosen else ""), str(c.n_params), _num(r.chi2, ".5g"),
                      _num(r.reduced_chi2), _num(r.p_value, ".3g"), _num(r.aic, ".5g"), _num(r.bic, ".5g"),
                      _num(c.criterion(sel.criterion) - best, ".3g"), escape(noise_words(r))],
                     "chosen" if r is sel.chosen else ""))  # fmt: skip
    # No fit times: the page, like fit.json, depends on the inputs alone (the same bytes from a batch).
    header = ["candidate", "k", "chi2", "chi2/dof", "p", "AIC", "BIC", f"Δ{crit}", "residuals"]
    return _table(header, rows) + f"<p>{escape(sel.reason)}</p>"


def _truth(a: Analysis) -> list[str]:
    """The heading and body of the comparison with a simulated run's true material (nothing for other sources)."""
    cmp = compare_truth(a)
    if cmp is None:
        return []
    err = (f"<p>Relative L2 error of the fitted f_r cos θi cos θo against the truth: "
           f"<b>{100 * cmp.error_at_samples:.3g} %</b> at the measured directions, <b>{100 * cmp.error_hemisphere:.3g} "
           f"%</b> over the hemisphere (θ up to {MAX_THETA_DEG:g}°).</p>")  # fmt: skip
    if cmp.params is None:
        return ["<h2>Against the truth (simulated run)</h2>", err,
                f"<p>Parameters not compared: {escape(str(cmp.why_not))}.</p>"]  # fmt: skip
    rows = [([escape(p.name), _num(p.fitted), _num(p.std_error, ".2g"), _num(p.true), _num(p.z, "+.2f")],
             "" if not abs(p.z) > 2 else "flag") for p in cmp.params]  # fmt: skip
    table = _table(["parameter", "fitted", "std error", "true", "(fitted − true) / σ"], rows)
    return ["<h2>Against the truth (simulated run)</h2>", err, table]


def page_warnings(a: Analysis) -> list[str]:
    """Every warning once: one the candidates share is listed once with their names, and a candidate's "at a
    bound" note names the bound itself (0, not the 6e-24 the optimiser stopped at)."""
    fitted = [c for c in a.selection.candidates if c.result is not None]
    by_text: dict[str, list[str]] = {}
    for w in a.warnings:
        owner = next((c for c in fitted if w.startswith(f"{c.name}: ")), None)
        if owner is None or owner.result is None:
            by_text.setdefault(w, [])
            continue
        text = w[len(owner.name) + 2 :]
        if text.startswith("at a bound:"):
            status = parameter_status(owner.result, a.spec(owner.name), a.samples.channels)
            at = ", ".join(f"{p.name} = {p.value_text()}" for p in status if p.bound is not None)
            text = f"at a bound: {at}; their std errors assume the bound is not there" if at else text
        by_text.setdefault(text, []).append(owner.name)
    out = []
    for text, names in by_text.items():
        if not names:
            out.append(text)
        elif len(names) == 1:
            out.append(f"{names[0]}: {text}")
        else:
            out.append(f"{text} (every one of {', '.join(names)})" if len(names) == len(fitted) and len(names) > 2
                       else f"{text} ({' and '.join(names)})")  # fmt: skip
    return out


def _figures(figs: Figures) -> str:
    parts = []
    for f in figs.files:
        img = f'<img src="figures/{escape(f.png.name)}" alt="{escape(f.name)}">'
        link = f'<a href="figures/{escape(f.svg.name)}">{img}</a>' if f.svg else img
        parts.append(f"<figure>{link}<figcaption>{escape(f.caption)}</figcaption></figure>")
    return "".join(parts)



_EXPORT_LABELS = {
    "material": "gonio model (JSON, model.serialize)",
    "mitsuba_xml": "Mitsuba 3 BSDF for stock Mitsuba, XML scene fragment",
    "mitsuba_json": "Mitsuba 3 BSDF for stock Mitsuba, scene dictionary (JSON)",
    "mitsuba_scene": "Mitsuba 3 scene: a patch of the material under a point light, renders as it is",
    "mitsuba_plugin_xml": "the exact model for gonio's Mitsuba plugin (renders only where gonio is installed)",
    "tabulated": "the model tabulated (RGL .bsdf) for stock Mitsuba's measured plugin",
    "mitsuba_measured_xml": "Mitsuba 3 measured BSDF reading the table, XML scene fragment",
    "mitsuba_measured_json": "Mitsuba 3 measured BSDF reading the table, scene dictionary (JSON)",
    "mitsuba_projection_xml": "the nearest stock diffuse + GGX BSDF (a projection), XML scene fragment",
    "mitsuba_projection_json": "the nearest stock diffuse + GGX BSDF (a projection), scene dictionary (JSON)",
    "gltf": "glTF 2.0 metal-roughness material (a projection: its error is in extras)",
    "gltf_asset": "glTF 2.0 asset: a sample patch with that material, for glTF viewers",
    "readme": "what each export is and how far each projection is from the model",
    "merl": "MERL .binary table",
}


def _exports(exports: Mapping[str, Path], page: Path, notes: Mapping[str, str] | None = None) -> str:
    items = []
    for kind, path in exports.items():
        rel = os.path.relpath(path, page.parent)
        label = escape((notes or {}).get(kind) or _EXPORT_LABELS.get(kind, kind))
        items.append(f'<li><a href="{escape(rel)}">{escape(path.name)}</a>: {label}</li>')
    return f"<ul>{''.join(items)}</ul>" if items else ""


def render_html(
    a: Analysis, figs: Figures, exports: Mapping[str, Path] | None = None, page: Path = Path("."),
    notes: Mapping[str, str] | None = None,
) -> str:
    """The report page as a string (see the module docstring for its order)."""
    r = a.selection.chosen
    name = a.source.path.name or str(a.source.path)
    banner = f'<p class="warn">{escape(a.source.warning)}</p>' if a.source.warning else ""
    warns = "".join(f"<li>{escape(w)}</li>" for w in page_warnings(a))
    body = [
        f"<h1>gonio analysis: {escape(name)}</h1>",
        f'<p class="verdict">{escape(a.verdict())}</p>', banner,
        "<h2>Source</h2>", _source(a),
        "<h2>Chosen model</h2>", _parameters(r, a),
        "<h3>Exports of the chosen model</h3>" if exports else "", _exports(exports or {}, page, notes),
        *_truth(a),
        "<h2>Model selection</h2>", _selection(a),
        "<h2>Warnings</h2>", f"<ul>{warns}</ul>" if warns else "<p>None.</p>",
        "<h2>Figures</h2>", _figures(figs),
        "<h2>Coverage of the BRDF domain</h2>", f"<p>{escape(figs.coverage.text())}</p>",
        f'<p class="muted">gonio {escape(gonio_version())}; fit.json holds every number of this page.</p>',
    ]  # fmt: skip
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>gonio analysis: {escape(name)}'
        f"</title><style>{CSS}</style></head><body>\n" + "\n".join(p for p in body if p) + "\n</body></html>\n"
    )


def write_html(
    a: Analysis, figs: Figures, path: str | Path, exports: Mapping[str, Path] | None = None,
    notes: Mapping[str, str] | None = None,
) -> Path:
    """Write the report page atomically, linking the exported files (``notes``: text per kind); returns its path."""
    text = render_html(a, figs, exports, Path(path), notes)
    return write_atomic(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))
