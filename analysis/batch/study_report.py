"""What a simulation study reports: per material, the error of each design against its captures and rig time.

Each design's outcomes are averaged over the seeds (matched by design and captures). A material's table
sets every design against its anchor: the dense grid in the study of bench/sweep_tradeoff, otherwise the
design with the most captures. The figure draws error against captures (top) and rig hours (bottom), one
column per material, the anchor's error dotted. For the sweep_tradeoff study a verdict per material says
whether, and where, each adaptive variant reaches the dense grid's error within its budget.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.batch.tradeoff import ADAPTIVE_VARIANTS, BUDGET
from analysis.tables import format_table, markdown_table

#: Below this a shape error is rounding: a Lambertian fit is a scale per channel, so it has no shape error.
SHAPELESS = 1e-9
#: Markers and colours of the sweep_tradeoff designs; other designs take the next of CYCLE.
STYLES: dict[str, tuple[str, str]] = {
    "grid": ("o-", "tab:blue"), "rusinkiewicz": ("s-", "tab:green"), "adaptive": ("D-", "tab:red"),
    "adaptive SNR 300": ("^-", "tab:purple"), "adaptive SNR 500": ("v-", "tab:brown"),
}  # fmt: skip
CYCLE = tuple(itertools.product("o^sDv<>", ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple")))


@dataclass(frozen=True)
class Outcome:
    """One design measured and fitted: captures, rig time (s), relative BRDF error (total, shape), chi2/dof."""

    strategy: str
    captures: int
    rig_time_s: float
    error: float
    shape_error: float
    reduced_chi2: float


def mean_outcomes(runs: Sequence[Sequence[Outcome]]) -> list[Outcome]:
    """Outcomes averaged over repeated runs (noise realisations), matched by design and captures."""
    groups: dict[tuple[str, int], list[Outcome]] = {}
    for run in runs:
        for o in run:
            groups.setdefault((o.strategy, o.captures), []).append(o)
    return [Outcome(k[0], k[1], *(float(np.mean([getattr(o, f) for o in g]))
                                  for f in ("rig_time_s", "error", "shape_error", "reduced_chi2")))
            for k, g in groups.items()]  # fmt: skip


def anchor_of(outcomes: Sequence[Outcome]) -> Outcome:
    """The design every other is compared with: the densest grid if there is one, else the most captures."""
    grids = [o for o in outcomes if o.strategy == "grid"]
    return max(grids or outcomes, key=lambda o: o.captures)


def headers(outcomes: Sequence[Outcome]) -> list[str]:
    """A material's table's header; the ratios are to the anchor (named "dense grid" when it is one)."""
    to = "ratio to dense grid" if anchor_of(outcomes).strategy == "grid" else "ratio to anchor"
    return ["design", "captures", "rig time (min)", "BRDF error", to, "shape error", to, "chi2/dof"]


def _ratio(x: float, ref: float) -> str:
    """x / ref, or a dash where the reference is zero to rounding (a Lambertian fit has no shape error)."""
    return f"{x / ref:.2f}" if ref > SHAPELESS else "-"


def table_rows(outcomes: Sequence[Outcome]) -> list[list[str]]:
    """The rows of a material's table (see headers), in the order the outcomes come."""
    a = anchor_of(outcomes)
    return [[o.strategy, str(o.captures), f"{o.rig_time_s / 60:.1f}", f"{o.error:.2e}", _ratio(o.error, a.error),
             f"{o.shape_error:.2e}", _ratio(o.shape_error, a.shape_error), f"{o.reduced_chi2:.2f}"]
            for o in outcomes]  # fmt: skip


def anchor_text(outcomes: Sequence[Outcome]) -> str:
    """How the anchor is named in headings: "the dense grid of N captures" or "<design> (N captures)"."""
    a = anchor_of(outcomes)
    if a.strategy == "grid":
        return f"the dense grid of {a.captures} captures"
    return f"{a.strategy} ({a.captures} captures)"


def _wins(runs: Sequence[Sequence[Outcome]]) -> str:
    """Per seed, whether each adaptive variant's last round is at or below that seed's dense grid."""
    parts = []
    for strat, _ in ADAPTIVE_VARIANTS:
        wins = 0
        for run in runs:
            dense = max((o for o in run if o.strategy == "grid"), key=lambda o: o.captures)
            last = max((o for o in run if o.strategy == strat), key=lambda o: o.captures)
            wins += last.error <= dense.error
        parts.append(f"{strat} at {BUDGET} at or below the dense grid in {wins} of {len(runs)} seeds")
    return "per seed: " + ", ".join(parts)


def tradeoff_verdict(name: str, res: Sequence[Outcome], runs: Sequence[Sequence[Outcome]]) -> str:
    """The sweep_tradeoff verdict of one material: the dense grid, and where each adaptive variant gets to."""
    dense = anchor_of(res)
    verdict = f"{name}: dense grid of {dense.captures} captures ({dense.rig_time_s / 3600:.2f} h rig time)"
    keys = [("BRDF error", "error")]
    if dense.shape_error > SHAPELESS:
        keys.append(("shape error", "shape_error"))
    for (label, key), strat in itertools.product(keys, [v[0] for v in ADAPTIVE_VARIANTS]):
        adaptive = [o for o in res if o.strategy == strat and o.captures <= BUDGET]
        if not adaptive:
            continue
        ref = getattr(dense, key)
        reach = next((o for o in adaptive if getattr(o, key) <= ref), None)
        best = min(adaptive, key=lambda o: getattr(o, key))
        verdict += (f"; {label} {ref:.2e}, {strat} best {getattr(best, key):.2e} at {best.captures} "
                    f"captures (ratio {getattr(best, key) / max(ref, 1e-300):.2f}), "
                    + (f"first at or below the dense grid's at {reach.captures} captures "
                       f"({reach.rig_time_s / 3600:.2f} h)" if reach
                       else "never below the dense grid's"))  # fmt: skip
    if all(any(o.strategy == s for run in runs for o in run) for s, _ in ADAPTIVE_VARIANTS):
        verdict += "; " + _wins(runs)
    return verdict


def text_report(results: Mapping[str, list[Outcome]], verdicts: Mapping[str, str]) -> str:
    """The tables for a terminal, each material's verdict (if any) after its table."""
    parts = []
    for name, res in results.items():
        a = anchor_of(res)
        verdict = f"\n{verdicts[name]}" if name in verdicts else ""
        parts.append(f"{name} (anchor: {anchor_text(res)}, error {a.error:.2e})\n"
                     + format_table(headers(res), table_rows(res)) + verdict)  # fmt: skip
    return "\n\n".join(parts) + "\n"


def markdown_report(results: Mapping[str, list[Outcome]], verdicts: Mapping[str, str]) -> str:
    """The tables and verdicts as markdown (the body of the sweep_tradeoff section of docs/benchmarks.md)."""
    tables = [f"**{name}** (anchor: {anchor_text(res)})\n\n" + markdown_table(headers(res), table_rows(res))
              for name, res in results.items()]  # fmt: skip
    listed = "\n".join(f"- {v}" for v in verdicts.values())
    return "\n\n".join(tables) + (f"\n\n{listed}" if listed else "") + "\n"


def plot(results: Mapping[str, list[Outcome]], path: Path) -> Path:
    """Error against captures (top) and rig hours (bottom), one column per material; writes a PNG atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from acquisition.files.atomic import write_atomic

    names = list(results)
    fig = Figure(figsize=(5.0 * len(names), 7.5))
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, len(names), squeeze=False)
    designs = list(dict.fromkeys(o.strategy for res in results.values() for o in res))
    others = iter(CYCLE)
    styles: dict[str, tuple[str, str]] = {}
    for d in designs:
        marker, colour = next(others) if d not in STYLES else ("", "")
        styles[d] = STYLES.get(d) or (f"{marker}-", colour)
    for col, name in enumerate(names):
        anchor = anchor_of(results[name])
        for row, key in enumerate(("captures", "rig_time_s")):
            ax = axes[row][col]
            for strat in designs:
                pts = sorted((o for o in results[name] if o.strategy == strat), key=lambda o: o.captures)
                if pts:
                    x = [o.captures if key == "captures" else o.rig_time_s / 3600.0 for o in pts]
                    fmt, colour = styles[strat]
                    ax.plot(x, [o.error for o in pts], fmt, color=colour, ms=4, label=strat)
            ax.axhline(anchor.error, color="0.4", ls=":", lw=1, label=f"anchor: {anchor_text(results[name])}")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("captures" if key == "captures" else "rig time (h)")
            ax.set_ylabel("relative BRDF error")
            ax.grid(True, which="both", alpha=0.3)
            if row == 0:
                ax.set_title(name, fontsize=10)
        axes[0][col].legend(fontsize=8)
    fig.tight_layout()
    return write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
