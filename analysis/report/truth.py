"""For a simulated run: the fitted parameters against the true ones, and the fitted BRDF's error against the truth.

Parameters are compared only when the truth is the same model class with the same fixed fields (a GGX
conductor fitted to a GGX conductor); otherwise the fitted numbers mean something else and only the BRDF
error is shown. Each compared parameter gets z = (fitted - true) / std error: honest error bars give |z| <= 2
for about 95 % of them.

The BRDF error is the relative L2 error of f_r cos(theta_i) cos(theta_o) (the reflected radiance per unit
irradiance, so grazing directions weigh what they contribute), in two places: at the measured directions, and
over the whole hemisphere up to ``MAX_THETA_DEG`` on a fixed grid of (theta_i, theta_o, phi_o - phi_i). A fit
can be excellent where the data are and wrong away from them; the two numbers side by side say which.
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from analysis.result import Analysis, Reference
from analysis.uncertainty import truth
from model.base import BRDF, Model
from model.geometry import degrees_to_vector, to_half_diff

if TYPE_CHECKING:  # matplotlib loads only where a figure is drawn: fit.json reads the comparison's numbers alone
    from matplotlib.figure import Figure

Array = npt.NDArray[np.float64]
MAX_THETA_DEG = 80.0
#: Characters per line of the note that replaces the parameter panel (9 pt text in a 4-inch panel).
WHY_NOT_CHARS = 48
#: Grid of the hemisphere comparison: theta_i and theta_o steps (deg) and the relative azimuth step (deg).
GRID_THETA_STEP_DEG, GRID_PHI_STEP_DEG = 5.0, 10.0


@dataclass(frozen=True)
class TrueParam:
    """One fitted number beside its true value; z = (fitted - true) / std error."""

    name: str
    fitted: float
    std_error: float
    true: float

    @property
    def z(self) -> float:
        """How many std errors the fit is off (NaN when the std error is zero or infinite)."""
        ok = math.isfinite(self.std_error) and self.std_error > 0
        return (self.fitted - self.true) / self.std_error if ok else math.nan


@dataclass(frozen=True)
class TruthComparison:
    """The comparison of the chosen fit with a simulated run's true material."""

    truth: str
    #: None when the truth is another model class (or other fixed fields): its parameters do not compare.
    params: tuple[TrueParam, ...] | None
    why_not: str | None
    error_at_samples: float
    error_hemisphere: float
    #: The hemisphere grid's (theta_h, theta_d) in degrees and the relative error of each direction pair.
    grid_half_diff: tuple[Array, Array]
    grid_rel_error: Array

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (fit.json's ``truth``)."""
        return {
            "truth": self.truth,
            "params": None if self.params is None else {p.name: {"fitted": p.fitted, "std_error": p.std_error,
                                                                 "true": p.true, "z": p.z} for p in self.params},
            "params_not_compared": self.why_not,
            "brdf_rel_l2_error_at_samples": self.error_at_samples,
            "brdf_rel_l2_error_hemisphere": self.error_hemisphere,
            "hemisphere_max_theta_deg": MAX_THETA_DEG,
        }  # fmt: skip


def _grid() -> tuple[Array, Array]:
    t = np.arange(0.0, MAX_THETA_DEG + 1e-9, GRID_THETA_STEP_DEG)
    p = np.arange(0.0, 360.0, GRID_PHI_STEP_DEG)
    ti, to, dp = (m.reshape(-1) for m in np.meshgrid(t, t, p, indexing="ij"))
    return degrees_to_vector(ti, np.zeros_like(ti)).astype(np.float64), degrees_to_vector(to, dp).astype(np.float64)


def _values(brdf: BRDF, wi: Array, wo: Array, channels: int) -> Array:
    f = np.asarray(brdf.eval(wi, wo), dtype=np.float64).reshape(wi.shape[0], -1)
    return np.broadcast_to(f, (wi.shape[0], channels)) if f.shape[1] == 1 else f


def _rel_l2(fit: Array, true: Array, weight: Array) -> float:
    den = float(np.sum(weight[:, None] * true**2))
    return math.sqrt(float(np.sum(weight[:, None] * (fit - true) ** 2)) / den) if den > 0 else math.nan


def _params(a: Analysis, true: Reference) -> tuple[tuple[TrueParam, ...] | None, str | None]:
    r = a.selection.chosen
    spec = a.spec(r.spec)
    model = true.brdf
    if not isinstance(model, Model) or type(model) is not spec.model:
        return None, f"the truth is a {type(model).__name__}, the chosen model a {spec.model.__name__}"
    differ = [k for k, v in spec.fixed.items() if getattr(model, k, v) != v]
    if differ:
        return None, "the truth differs in the fields the fit holds fixed: " + ", ".join(
            f"{k} = {getattr(model, k)!r} (fit: {spec.fixed[k]!r})" for k in differ)
    # Each label's field and channel, in the order spec.labels gives them.
    fields = [(q.name, i if q.per_channel else None) for q, k in zip(spec.params, spec.sizes(a.samples.channels),
                                                                     strict=True) for i in range(k)]  # fmt: skip
    out = []
    for name, value, se, (field, ch) in zip(r.names, r.values, r.std_errors, fields, strict=True):
        v = np.atleast_1d(np.asarray(getattr(model, field), dtype=np.float64))
        # A shared fitted value against a per-channel truth compares with nothing in particular: NaN.
        tv = float(v[0]) if v.size == 1 else float(v[ch]) if ch is not None and ch < v.size else math.nan
        out.append(TrueParam(name, float(value), float(se), tv))
    return tuple(out), None


def compare_truth(a: Analysis) -> TruthComparison | None:
    """The chosen fit against a simulated run's true material (None when the source has no truth)."""
    true = truth(a)
    if true is None:
        return None
    s, c = a.samples, a.samples.channels
    model = a.selection.chosen.model
    w_s = np.abs(s.wi[:, 2] * s.wo[:, 2])
    at = _rel_l2(_values(model, s.wi, s.wo, c), _values(true.brdf, s.wi, s.wo, c), w_s)
    wi, wo = _grid()
    fit_g, true_g = _values(model, wi, wo, c), _values(true.brdf, wi, wo, c)
    w_g = wi[:, 2] * wo[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.sqrt(np.mean((fit_g - true_g) ** 2, axis=1) / np.maximum(np.mean(true_g**2, axis=1), 1e-300))
    th, _, td, _ = to_half_diff(wi, wo)
    params, why = _params(a, true)
    label = type(true.brdf).__name__ if isinstance(true.brdf, Model) else true.label
    return TruthComparison(label, params, why, at, _rel_l2(fit_g, true_g, w_g), (np.degrees(th), np.degrees(td)),
                           rel)  # fmt: skip


def truth_figure(cmp: TruthComparison) -> tuple[Figure, str]:
    """Left: each parameter's z against the truth; right: the relative BRDF error over (theta_h, theta_d)."""
    from analysis.report.layout import Margins, panel_figure

    fig, axes, cax = panel_figure((10.5, 3.8), 1, 2, Margins(left=0.75, bottom=0.6, top=0.35, wgap=0.75,
                                                              colorbar=0.15))  # fmt: skip
    left, right = axes[0]
    if cmp.params:
        z = np.array([p.z for p in cmp.params])
        y = np.arange(len(z))
        left.axvspan(-2, 2, color="0.92", zorder=0)
        left.barh(y, np.clip(np.nan_to_num(z), -6, 6), color=np.where(np.abs(z) <= 2, "#009E73", "#D55E00"))
        left.set_yticks(y, [p.name for p in cmp.params], fontsize=8)
        left.invert_yaxis()
        left.set(xlim=(-6, 6), xlabel="(fitted − true) / std error (clipped at ±6)",
                 title="fitted against true parameters (grey: ±2σ)")  # fmt: skip
    else:
        left.set_axis_off()
        # Wrapped here to the panel's width: matplotlib's wrap=True wraps at the figure's edge, so a long reason
        # ran across the right panel.
        why = textwrap.fill(f"parameters not compared: {cmp.why_not}", width=WHY_NOT_CHARS)
        left.text(0.5, 0.5, why, ha="center", va="center", transform=left.transAxes, fontsize=9)
    th, td = cmp.grid_half_diff
    order = np.argsort(cmp.grid_rel_error)
    sc = right.scatter(th[order], td[order], c=np.log10(np.maximum(cmp.grid_rel_error[order], 1e-4)), s=4,
                       cmap="viridis", vmin=-3, vmax=0, rasterized=True)  # fmt: skip
    right.set(xlim=(0, 90), ylim=(0, 90), xlabel="θh (deg)", ylabel="θd (deg)",
              title=f"relative error of the fitted BRDF: {100 * cmp.error_hemisphere:.2g} % over the hemisphere")
    fig.colorbar(sc, cax=cax, label="log10 |fit − truth| / truth")
    cap = (f"Against the simulated material ({cmp.truth}): relative L2 error of f_r cos θi cos θo "
           f"{100 * cmp.error_at_samples:.3g} % at the measured directions, {100 * cmp.error_hemisphere:.3g} % over "
           f"the hemisphere up to {MAX_THETA_DEG:g}°.")  # fmt: skip
    if cmp.params:
        n_ok = sum(1 for p in cmp.params if abs(p.z) <= 2)
        cap += f" {n_ok} of {len(cmp.params)} parameters within 2 std errors of the truth."
    return fig, cap
