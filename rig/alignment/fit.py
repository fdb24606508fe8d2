"""The least-squares fit of a rig's imperfections to the board's corners and the lamp's highlights.

Residuals are pixel differences between observed and predicted positions (``rig.alignment.model``), each
divided by its standard error: the highlight's from its peak fit (at least ``HIGHLIGHT_FLOOR_PX``) and, added
in quadrature, the highlights' own scatter about the fit beyond it; the corners' from their own scatter about
the fit (both estimated in a first pass, then fixed, with corners beyond 5 of it dropped as misdetections).
The highlights scatter beyond their peak fits where the joints stand off what they read: a servo rests
anywhere within one encoder count (0.09 deg), and the mirror image moves with the lamp's and the stage's
angles by 1-2 px per such count, while the corners, about the board's centre, barely move. A scatter beyond
``HIGHLIGHT_SCATTER_LIMIT`` times what the peak fits and the joints' counts explain is warned of.

The parameters' covariance is the inverse normal matrix, scaled up by chi2/dof where the residuals exceed
their errors (the model then explains less than the noise predicts: the uncertainty must say so), widened
where a jackknife over captures scatters more (errors a frame's corners share), plus the systematic term of
a bias common to every highlight (the peak model's accuracy, ``HIGHLIGHT_SYSTEMATIC_PX``). Pairs of
parameters correlated beyond ``MAX_CORRELATION`` are named: the captures cannot tell them apart.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from model.errors import InputError
from rig.alignment.model import coat_peak, predict
from rig.alignment.observe import FrameObservation, Highlight
from rig.instrument.alignment import PARAMETERS, Alignment, alignment_of, parameters_of
from rig.instrument.calibration_file import RESIDUAL_LIMIT
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints

FloatArray = npt.NDArray[np.float64]

HIGHLIGHT_FLOOR_PX = 0.02
#: How well the coat's modelled peak matches a rendered highlight (px): observed minus modelled peaks were
#: within +-0.02 px on a perfect rig (alpha 0.01, 480 px); a bias common to every highlight is not seen
#: in their scatter, so it enters the covariance as a systematic term (see _systematic).
HIGHLIGHT_SYSTEMATIC_PX = 0.02
MAX_CORRELATION = 0.95
#: Highlights scattering about the fit by more than this many times what their peak fits and their joints'
#: encoder counts explain are warned of.
HIGHLIGHT_SCATTER_LIMIT = 2.0
#: User-facing names of the fit parameters (the wedge is reported as tilt and azimuth, see quantities()).
LABELS = {"wedge_x_deg": "sample_tilt_deg (x)", "wedge_y_deg": "sample_tilt_deg (y)",
          "offset_x_mm": "sample_offset_mm x", "offset_y_mm": "sample_offset_mm y",
          "offset_z_mm": "sample_offset_mm z"}  # fmt: skip


class CalibrationError(InputError, ValueError):
    """The captures cannot calibrate the rig (too few, nothing found); the message says what to change."""


@dataclass(frozen=True)
class Capture:
    """One calibration capture: the joints read back (degrees) and what its frame showed."""

    joints: Joints
    seen: FrameObservation


@dataclass(frozen=True)
class GeometryFit:
    """The fitted imperfections with their covariance, and how well they explain the captures."""

    names: tuple[str, ...]
    values: FloatArray
    covariance: FloatArray
    alignment: Alignment
    corner_sigma_px: float
    chi2: float
    dof: int
    corner_residuals_px: list[FloatArray]
    highlight_residuals_px: list[FloatArray | None]
    warnings: tuple[str, ...] = field(default=())
    #: The highlights' scatter about the fit beyond their peak fits' errors (px), added to each in quadrature.
    highlight_sigma_px: float = 0.0

    @property
    def reduced_chi2(self) -> float:
        """chi2 per degree of freedom (1 where the residuals are the noise)."""
        return self.chi2 / max(self.dof, 1)

    def std_errors(self) -> FloatArray:
        """Standard errors of the fit parameters."""
        return np.sqrt(np.maximum(np.diag(self.covariance), 0.0))

    def correlation(self) -> FloatArray:
        """The parameters' correlation matrix."""
        se = self.std_errors()
        with np.errstate(invalid="ignore", divide="ignore"):
            out: FloatArray = self.covariance / np.outer(se, se)
        return np.nan_to_num(out)

    def quantities(self) -> dict[str, tuple[float | list[float], float | list[float]]]:
        """Every quantity of ``[simulation.misalignment]``'s geometry: name -> (value, standard error)."""
        v = dict(zip(self.names, self.values, strict=True))
        idx = {n: i for i, n in enumerate(self.names)}
        se = self.std_errors()
        out: dict[str, tuple[float | list[float], float | list[float]]] = {}
        for name in ("light_zero_deg", "camera_zero_deg", "tilt_zero_deg", "roll_zero_deg", "yaw_zero_deg"):
            if name in idx:
                out[name] = (float(v[name]), float(se[idx[name]]))
        if "wedge_x_deg" in idx:
            wx, wy = v["wedge_x_deg"], v["wedge_y_deg"]
            tau = math.hypot(wx, wy)
            j = [idx["wedge_x_deg"], idx["wedge_y_deg"]]
            cov = self.covariance[np.ix_(j, j)]
            if tau > 0:
                d_tau = np.array([wx, wy]) / tau
                d_psi = np.degrees(np.array([-wy, wx]) / (tau * tau))
                tau_se, psi_se = float(np.sqrt(d_tau @ cov @ d_tau)), float(np.sqrt(d_psi @ cov @ d_psi))
            else:
                tau_se, psi_se = float(np.sqrt(np.trace(cov) / 2)), 180.0
            out["sample_tilt_deg"] = (tau, tau_se)
            # An azimuth is only as good as the tilt it belongs to: at most 180 deg uncertain.
            out["sample_tilt_azimuth_deg"] = (math.degrees(math.atan2(wy, wx)), min(psi_se, 180.0))
        else:
            out["sample_tilt_deg"] = (0.0, 0.0)
            out["sample_tilt_azimuth_deg"] = (0.0, 0.0)
        offset = [float(v[n]) if n in idx else 0.0 for n in ("offset_x_mm", "offset_y_mm", "offset_z_mm")]
        offset_se = [float(se[idx[n]]) if n in idx else 0.0 for n in ("offset_x_mm", "offset_y_mm", "offset_z_mm")]
        out["sample_offset_mm"] = (offset, offset_se)
        return out


@dataclass(frozen=True)
class _Problem:
    """The captures, the camera and the corners' error: residuals for a parameter vector."""

    geometry: RigGeometry
    names: tuple[str, ...]
    captures: Sequence[Capture]
    corners_local: FloatArray
    focal_px: float
    size: tuple[int, int]
    corner_sigma: float
    keep: list[npt.NDArray[np.bool_]]
    #: Per capture, the coat's peak minus the mirror point (px), from the last estimate (see coat_peak).
    shifts: list[FloatArray]
    #: The highlights' scatter beyond their peak fits (px): see the module's docstring.
    highlight_sigma: float = 0.0

    def highlight_error(self, highlight: Highlight) -> float:
        """A highlight's standard error (px): its peak fit's (at least the floor) and the highlights' scatter."""
        return math.hypot(max(highlight.std_error_px, HIGHLIGHT_FLOOR_PX), self.highlight_sigma)

    def rows(self) -> list[slice]:
        """Which residuals belong to which capture (kept corners x 2, then the highlight's 2)."""
        out, start = [], 0
        for cap, k in zip(self.captures, self.keep, strict=True):
            n = 2 * int(np.sum(k)) + (2 if cap.seen.highlight is not None else 0)
            out.append(slice(start, start + n))
            start += n
        return out

    def residuals(self, p: FloatArray) -> FloatArray:
        """Normalised residuals (dimensionless) of the kept corners and every highlight."""
        return self.evaluate(p)[0]

    def evaluate(self, p: FloatArray) -> tuple[FloatArray, list[FloatArray], list[FloatArray | None]]:
        """Normalised residuals, and the pixel residuals of every capture's corners and highlight."""
        a = alignment_of(self.names, p)
        parts, corner_res, hl_res = [], [], []
        for cap, k, shift in zip(self.captures, self.keep, self.shifts, strict=True):
            seen = cap.seen
            corners, highlight = predict(self.geometry, cap.joints, a, self.corners_local[seen.corner_ids],
                                         self.focal_px, self.size)  # fmt: skip
            d = corners - seen.corners_px
            corner_res.append(d)
            parts.append((d[k] / self.corner_sigma).ravel())
            if seen.highlight is not None:
                h = highlight + shift - np.array([seen.highlight.x, seen.highlight.y])
                hl_res.append(h)
                parts.append(h / self.highlight_error(seen.highlight))
            else:
                hl_res.append(None)
        return np.concatenate(parts) if parts else np.zeros(0), corner_res, hl_res


def _highlight_scatter(captures: Sequence[Capture], residuals: list[FloatArray | None], n_parameters: int) -> float:
    """The highlights' scatter about a fit beyond their peak fits' errors (px; 0 where those explain it).

    Each highlight gives two residuals; the fit's parameters take up to a fraction ``n_parameters / n`` of their
    spread (the highlights fix the light's zero and share the rest with the corners), so their mean square is
    scaled up by that much before the peak fits' own share is taken off.
    """
    ms, own, n = 0.0, 0.0, 0
    for h, cap in zip(residuals, captures, strict=True):
        if h is not None and cap.seen.highlight is not None:
            ms += float(h @ h)
            own += 2 * max(cap.seen.highlight.std_error_px, HIGHLIGHT_FLOOR_PX) ** 2
            n += 2
    if n <= n_parameters:
        return 0.0
    return math.sqrt(max(ms / (n - min(n_parameters, n // 2)) - own / n, 0.0))


def _joint_jitter(geometry: RigGeometry, captures: Sequence[Capture], a: Alignment, focal_px: float,
                  size: tuple[int, int], joint_std_deg: Mapping[str, float]) -> float:  # fmt: skip
    """How far the joints' own errors move the highlights (px, RMS per axis) on the rig ``a`` describes."""
    step, total, n = 1e-3, 0.0, 0  # deg: the highlight is smooth in the joints over far more than this
    for cap in captures:
        if cap.seen.highlight is None:
            continue
        base = cap.joints.as_dict()
        for name in geometry.joint_names:
            sd = float(joint_std_deg.get(name, 0.0))
            if sd > 0.0:
                up = predict(geometry, Joints.from_dict({**base, name: float(base[name]) + step}), a, np.zeros((0, 3)),
                             focal_px, size)[1]  # fmt: skip
                down = predict(geometry, Joints.from_dict({**base, name: float(base[name]) - step}), a,
                               np.zeros((0, 3)), focal_px, size)[1]  # fmt: skip
                total += float(np.sum(((up - down) / (2 * step) * sd) ** 2))
        n += 2
    return math.sqrt(total / n) if n else 0.0


def _systematic(jac: FloatArray, problem: _Problem) -> FloatArray:
    """Covariance from a shift of HIGHLIGHT_SYSTEMATIC_PX common to every highlight, in x and in y."""
    out = np.zeros((jac.shape[1], jac.shape[1]))
    rows = problem.rows()
    normal = jac.T @ jac
    for axis in (0, 1):
        shift = np.zeros(jac.shape[0])
        for cap, sl in zip(problem.captures, rows, strict=True):
            h = cap.seen.highlight
            if h is not None:
                shift[sl.stop - 2 + axis] = HIGHLIGHT_SYSTEMATIC_PX / problem.highlight_error(h)
        if shift.any():
            dp = np.linalg.lstsq(normal, jac.T @ shift, rcond=None)[0]
            out += np.outer(dp, dp)
    return out


def _with_jackknife(cov: FloatArray, jac: FloatArray, r: FloatArray, rows: list[slice]) -> FloatArray:
    """The covariance, widened where leaving out one capture at a time moves a parameter more than it says.

    A capture's corners share its render, its blur and the detector's view of it, so their errors are not
    independent: the normal matrix counts each as a separate look and underrates quantities a whole frame
    carries (the camera's angle, seen through the board's foreshortening). The linearised jackknife over
    captures (the independent units) measures that scatter; each parameter's variance is the larger of the
    two, the correlations the model's.
    """
    n = len(rows)
    if n < 4:
        return cov
    normal = jac.T @ jac
    grad = jac.T @ r
    deltas = []
    for sl in rows:
        jk, rk = jac[sl], r[sl]
        try:
            deltas.append(np.linalg.solve(normal - jk.T @ jk, -(grad - jk.T @ rk)))
        except np.linalg.LinAlgError:
            return cov
    d = np.asarray(deltas)
    jack = (n - 1) / n * np.sum((d - d.mean(axis=0)) ** 2, axis=0)
    model = np.diag(cov)
    scale = np.sqrt(np.maximum(jack, model) / np.where(model > 0, model, 1.0))
    out: FloatArray = cov * np.outer(scale, scale)
    return out


def _shift(geometry: RigGeometry, capture: Capture, a: Alignment, focal_px: float, size: tuple[int, int],
           alpha: float) -> FloatArray:  # fmt: skip
    if capture.seen.highlight is None:
        return np.zeros(2)
    _, mirror = predict(geometry, capture.joints, a, np.zeros((0, 3)), focal_px, size)
    return coat_peak(geometry, capture.joints, a, focal_px, size, alpha) - mirror


def fit_geometry(
    geometry: RigGeometry,
    captures: Sequence[Capture],
    corners_local_m: FloatArray,
    focal_px: float,
    size: tuple[int, int],
    *,
    start: Alignment | None = None,
    fixed: Sequence[str] = (),
    alpha: float | None = None,
    joint_std_deg: Mapping[str, float] | None = None,
) -> GeometryFit:
    """Fit the layout's imperfections (``rig.alignment.model.PARAMETERS``, less ``fixed``) to the captures.

    ``alpha`` is the coat's GGX roughness: with it the highlights are compared with the coat's modelled
    peak (``coat_peak``) instead of the bare mirror point. ``joint_std_deg``: each joint's standard error
    about what it reads (deg; an encoder count / sqrt(12)), which the highlights' scatter is judged against.
    """
    names = tuple(n for n in PARAMETERS[geometry.layout] if n not in fixed)
    n_corners = sum(len(c.seen.corner_ids) for c in captures)
    n_highlights = sum(c.seen.highlight is not None for c in captures)
    if n_corners == 0:
        raise CalibrationError("the board was found in no capture: is it mounted, lit and in view?")
    keep = [np.ones(len(c.seen.corner_ids), dtype=bool) for c in captures]
    x0 = parameters_of(names, start or Alignment())
    sigma = 0.1
    hl_sigma = 0.0
    result = None
    shifts = [np.zeros(2) for _ in captures]
    for _ in range(2):  # the scatters and the peaks' shifts are only known after a first fit
        problem = _Problem(geometry, names, captures, corners_local_m, focal_px, size, sigma, keep, shifts, hl_sigma)
        result = least_squares(problem.residuals, x0, method="trf", x_scale="jac", diff_step=1e-7, xtol=1e-12,
                               ftol=1e-12)  # fmt: skip
        x0 = result.x
        _, corner_res, hl_res = problem.evaluate(result.x)
        flat = np.concatenate([d[k] for d, k in zip(corner_res, keep, strict=True)]) if n_corners else np.zeros((0, 2))
        sigma = max(float(np.sqrt(np.mean(flat**2))), 1e-3) if flat.size else sigma
        keep = [np.all(np.abs(d) < 5 * sigma, axis=1) for d in corner_res]
        hl_sigma = _highlight_scatter(captures, hl_res, len(names))
        if alpha is not None:
            estimate = alignment_of(names, result.x)
            shifts = [_shift(geometry, c, estimate, focal_px, size, alpha) for c in captures]
    assert result is not None
    problem = _Problem(geometry, names, captures, corners_local_m, focal_px, size, sigma, keep, shifts, hl_sigma)
    result = least_squares(problem.residuals, result.x, method="trf", x_scale="jac", diff_step=1e-7, xtol=1e-12,
                           ftol=1e-12)  # fmt: skip
    r, corner_res, hl_res = problem.evaluate(result.x)
    jac = result.jac
    dof = len(r) - len(names)
    if dof <= 0:
        raise CalibrationError(f"{len(r)} measurements cannot fit {len(names)} parameters: take more captures")
    chi2 = float(r @ r)
    try:
        cov = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        cov = np.linalg.pinv(jac.T @ jac)
    cov *= max(1.0, chi2 / dof)
    cov = _with_jackknife(cov, jac, r, problem.rows())
    cov = cov + _systematic(jac, problem)
    warnings = []
    if n_highlights == 0 and "light_zero_deg" in names:
        warnings.append("no capture showed the lamp's highlight: light_zero_deg rests on nothing but its start value")
    if chi2 / dof > RESIDUAL_LIMIT:
        # Seen with a rough board coat (GGX alpha 0.03): its highlight's peak leans off the modelled one by
        # more than its error, and the wedge takes the lean; scaling the errors by chi2 does not cover a bias.
        warnings.append(f"the residuals are {chi2 / dof:.2f}x their noise (chi2/dof above {RESIDUAL_LIMIT:g}): "
                        "the rig's model does not explain these captures and the errors understate the truth; a "
                        "glossier board coat (GGX alpha 0.01 or less, told with --alpha) or a look at the highlights "
                        "helps")  # fmt: skip
    found = [c.seen.highlight for c in captures if c.seen.highlight is not None]
    if found:
        own = math.sqrt(float(np.mean([max(h.std_error_px, HIGHLIGHT_FLOOR_PX) ** 2 for h in found])))
        jitter = _joint_jitter(geometry, captures, alignment_of(names, result.x), focal_px, size, joint_std_deg or {})
        if math.hypot(own, hl_sigma) > HIGHLIGHT_SCATTER_LIMIT * math.hypot(own, jitter):
            # The scatter is in the errors; but what makes highlights scatter (a lean, a loose joint) can bias them
            # all alike, which no scatter shows: it is said.
            warnings.append(f"the highlights scatter {hl_sigma:.2f} px about the fit, beyond their peak fits' "
                            f"{own:.2g} px and the {jitter:.2g} px their joints' encoder counts move them by: the "
                            "rig's model does not explain them and the errors may understate the truth (the "
                            "scatter is in them, a bias common to the highlights is not); a glossier board coat "
                            "(GGX alpha 0.01 or less, told with --alpha) or a look at the highlights and the joints "
                            "helps")  # fmt: skip
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.outer(np.where(se > 0, se, 1.0), np.where(se > 0, se, 1.0))
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if abs(corr[i, j]) > MAX_CORRELATION:
                a, b = LABELS.get(names[i], names[i]), LABELS.get(names[j], names[j])
                warnings.append(
                    f"{a} and {b} are correlated (r = {corr[i, j]:+.3f}): these captures cannot tell them apart; "
                    "add captures at other stage angles (more --captures)"
                )
    return GeometryFit(names, np.asarray(result.x), cov, alignment_of(names, result.x), sigma, chi2, dof,
                       corner_res, hl_res, tuple(warnings), hl_sigma)  # fmt: skip
