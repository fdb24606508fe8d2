"""Sweeps: the lists of BRDF direction pairs a run measures, in degrees, before any rig is involved.

Every generator returns a float64 array of shape (N, 4) with columns theta_i, phi_i, theta_o, phi_o in
degrees (local frame, z = sample normal, both directions pointing away from the surface; docs/architecture.md).
Rows are *normalised* (phi in [0, 360); phi = 0 where theta = 0, since the azimuth of the pole is
undefined; theta within 1e-9 of 0 or 90 snapped onto it) and *deduplicated*: rows whose four normalised
angles all agree within ``DEDUPE_TOL_DEG`` are one point, and the first occurrence is kept, so the order
is the documented generation order with repeats removed. Nothing here knows about reachability: the
plan (``rig.run.planning.plan``) checks every row against the rig and lists the unreachable ones with their reasons.

Rusinkiewicz (1998) half/difference grids can produce pairs with a direction below the horizon: those
are not reflection directions at all, so ``rusinkiewicz`` leaves them out, and ``rusinkiewicz_sweep``
returns them separately (``HalfDiffSweep.below_horizon``) so a caller can report how many were
discarded and which.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model.geometry import degrees_to_vector, from_half_diff, to_half_diff

FloatArray = npt.NDArray[np.float64]

#: Rows whose normalised angles (degrees) all agree within this are one point (up to twice this may merge).
DEDUPE_TOL_DEG = 1e-9
COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o")
#: Half-cell offsets of the grids used to find near-equal rows: 2^4 grids catch every pair within tolerance.
_SHIFTS = np.array(list(itertools.product((0.0, 0.5), repeat=4)))


def normalise(points_deg: npt.ArrayLike, tol_deg: float = DEDUPE_TOL_DEG) -> FloatArray:
    """Rows (..., 4) in degrees with phi in [0, 360), phi = 0 at theta = 0, and theta snapped onto 0 or 90."""
    p = np.array(points_deg, dtype=np.float64, copy=True)
    for t, f in ((0, 1), (2, 3)):
        theta = p[..., t]
        theta[np.abs(theta) <= tol_deg] = 0.0
        theta[np.abs(theta - 90.0) <= tol_deg] = 90.0
        # + 0.0 turns -0.0 into 0.0; values a hair under 360 wrap to 0 so 359.9999999999 equals 0.
        phi = np.mod(p[..., f], 360.0) + 0.0
        phi[phi >= 360.0 - tol_deg] = 0.0
        phi[theta == 0.0] = 0.0
        p[..., f] = phi
    return p


def unique_rows(points_deg: FloatArray, tol_deg: float = DEDUPE_TOL_DEG) -> npt.NDArray[np.bool_]:
    """Mask of rows (N, 4) to keep: the first of every group that agrees within ``tol_deg`` degrees."""
    n = len(points_deg)
    index = np.arange(n)
    if n < 2:
        return np.ones(n, dtype=bool)
    # Two rows within tol in every column share a cell of size 2*tol in at least one of 16 half-shifted
    # grids; propagating the smallest row index through shared cells until nothing changes labels every
    # connected group by its first row. Vectorised, so 1e5 rows take well under a second.
    scaled = points_deg / (2.0 * tol_deg)
    label = index.copy()
    while True:
        before = label.copy()
        for shift in _SHIFTS:
            keys = np.floor(scaled + shift)
            order = np.lexsort(keys.T[::-1])
            ordered = keys[order]
            change = np.r_[False, np.any(ordered[1:] != ordered[:-1], axis=1)]
            low = np.minimum.reduceat(label[order], np.flatnonzero(change | (np.arange(n) == 0)))
            label[order] = low[np.cumsum(change)]
        if np.array_equal(label, before):
            return label == index


def _finish(points_deg: npt.ArrayLike) -> FloatArray:
    """Normalised, deduplicated (N, 4) float64 rows in their given order."""
    p = normalise(np.asarray(points_deg, dtype=np.float64).reshape(-1, 4))
    out: FloatArray = np.ascontiguousarray(p[unique_rows(p)])
    return out


def _values(name: str, values: Sequence[float], lo: float, hi: float) -> FloatArray:
    """A 1-D float array of angles in degrees, each finite and in [lo, hi]; ValueError names the bad one."""
    a = np.asarray(values, dtype=np.float64).reshape(-1)
    for i, v in enumerate(a.tolist()):
        if not (math.isfinite(v) and lo <= v <= hi):
            raise ValueError(f"{name}[{i}] = {v!r} deg, expected a finite angle in [{lo:g}, {hi:g}] deg")
    return a


def grid(
    theta_i_deg: Sequence[float],
    theta_o_deg: Sequence[float],
    phi_o_deg: Sequence[float] = (180.0,),
    phi_i_deg: Sequence[float] = (0.0,),
) -> FloatArray:
    """Every combination of the given angles in degrees, (N, 4); theta_i outermost, then phi_i, theta_o, phi_o."""
    ti = _values("theta_i_deg", theta_i_deg, 0.0, 90.0)
    to = _values("theta_o_deg", theta_o_deg, 0.0, 90.0)
    po = _values("phi_o_deg", phi_o_deg, -math.inf, math.inf)
    pi = _values("phi_i_deg", phi_i_deg, -math.inf, math.inf)
    mesh = np.meshgrid(ti, pi, to, po, indexing="ij")
    return _finish(np.stack([m.reshape(-1) for m in mesh], axis=-1))


def in_plane(theta_i_deg: Sequence[float], theta_o_deg: Sequence[float], *, phi_i_deg: float = 0.0) -> FloatArray:
    """Slices in the plane of incidence, degrees, (N, 4); signed theta_o: > 0 opposite the light, < 0 its side.

    theta_o > 0 gives phi_o = phi_i + 180 (the forward-scattering side, where the mirror direction lies),
    theta_o < 0 gives phi_o = phi_i (back towards the light). Order: theta_i outermost, then theta_o.
    """
    ti = _values("theta_i_deg", theta_i_deg, 0.0, 90.0)
    to = _values("theta_o_deg", theta_o_deg, -90.0, 90.0)
    phi_i = float(_values("phi_i_deg", [phi_i_deg], -math.inf, math.inf)[0])
    t_i, t_o = (m.reshape(-1) for m in np.meshgrid(ti, to, indexing="ij"))
    phi_o = np.where(t_o > 0.0, phi_i + 180.0, phi_i)
    return _finish(np.stack([t_i, np.full_like(t_i, phi_i), np.abs(t_o), phi_o], axis=-1))


def half_diff_to_directions(
    theta_h_deg: npt.ArrayLike, theta_d_deg: npt.ArrayLike, phi_d_deg: npt.ArrayLike, phi_h_deg: npt.ArrayLike
) -> FloatArray:
    """Rusinkiewicz half/difference angles in degrees (broadcast) to rows (..., 4) of BRDF angles in degrees.

    Not normalised or filtered: a direction below the horizon comes out with theta > 90.
    """
    th, td, pd, ph = (
        np.radians(np.asarray(x, dtype=np.float64)) for x in (theta_h_deg, theta_d_deg, phi_d_deg, phi_h_deg)
    )
    wi, wo = from_half_diff(th, ph, td, pd)
    cols = []
    for w in (wi, wo):
        cols.append(np.degrees(np.arctan2(np.hypot(w[..., 0], w[..., 1]), w[..., 2])))
        cols.append(np.degrees(np.arctan2(w[..., 1], w[..., 0])))
    out: FloatArray = np.stack(cols, axis=-1).astype(np.float64)
    return out


def directions_to_half_diff(points_deg: npt.ArrayLike) -> FloatArray:
    """Rows (..., 4) of BRDF angles in degrees to (..., 4) columns theta_h, theta_d, phi_d, phi_h in degrees.

    Azimuths come out in (-180, 180]; phi_h is meaningless at theta_h = 0 and phi_d at theta_d = 0.
    """
    p = np.asarray(points_deg, dtype=np.float64)
    wi = degrees_to_vector(p[..., 0], p[..., 1])
    wo = degrees_to_vector(p[..., 2], p[..., 3])
    theta_h, phi_h, theta_d, phi_d = to_half_diff(wi, wo)
    out: FloatArray = np.degrees(np.stack([theta_h, theta_d, phi_d, phi_h], axis=-1)).astype(np.float64)
    return out


@dataclass(frozen=True)
class HalfDiffSweep:
    """A Rusinkiewicz grid: measurable rows, and the half/difference combinations that left the hemisphere.

    ``points`` is what ``rusinkiewicz`` returns: (N, 4) BRDF angles in degrees, normalised and
    deduplicated. ``below_horizon`` holds the dropped combinations as (M, 4) rows theta_h, theta_d,
    phi_d, phi_h in degrees: for them wi or wo points below the sample's surface, so they are not
    reflection geometries (unlike unreachable points, which exist but this rig cannot place).
    ``combinations`` counts every combination asked for; the rest merged as duplicates (e.g. every
    phi_h at theta_h = 0 gives the same pair).
    """

    points: FloatArray
    below_horizon: FloatArray
    combinations: int

    @property
    def below_horizon_count(self) -> int:
        """Number of combinations dropped because a direction was below the horizon."""
        return len(self.below_horizon)

    @property
    def duplicate_count(self) -> int:
        """Number of above-horizon combinations that repeated an earlier pair."""
        return self.combinations - self.below_horizon_count - len(self.points)


def rusinkiewicz_sweep(
    theta_h_deg: Sequence[float],
    theta_d_deg: Sequence[float],
    phi_d_deg: Sequence[float],
    phi_h_deg: Sequence[float] = (0.0,),
) -> HalfDiffSweep:
    """A half/difference grid in degrees with its below-horizon combinations kept aside (see ``HalfDiffSweep``).

    Order: theta_h outermost, then theta_d, phi_d, phi_h.
    """
    th = _values("theta_h_deg", theta_h_deg, 0.0, 90.0)
    td = _values("theta_d_deg", theta_d_deg, 0.0, 90.0)
    pd = _values("phi_d_deg", phi_d_deg, -math.inf, math.inf)
    ph = _values("phi_h_deg", phi_h_deg, -math.inf, math.inf)
    combos = np.stack([m.reshape(-1) for m in np.meshgrid(th, td, pd, ph, indexing="ij")], axis=-1)
    rows = half_diff_to_directions(combos[:, 0], combos[:, 1], combos[:, 2], combos[:, 3])
    # Exactly grazing pairs come out a rounding error past 90 deg; they are on the horizon, not below it.
    below = (rows[:, 0] > 90.0 + DEDUPE_TOL_DEG) | (rows[:, 2] > 90.0 + DEDUPE_TOL_DEG)
    kept = rows[~below]
    kept[:, 0] = np.minimum(kept[:, 0], 90.0)
    kept[:, 2] = np.minimum(kept[:, 2], 90.0)
    return HalfDiffSweep(points=_finish(kept), below_horizon=combos[below], combinations=len(combos))


def rusinkiewicz(
    theta_h_deg: Sequence[float],
    theta_d_deg: Sequence[float],
    phi_d_deg: Sequence[float],
    phi_h_deg: Sequence[float] = (0.0,),
) -> FloatArray:
    """Half/difference grid (Rusinkiewicz 1998) in degrees as (N, 4) BRDF angles; below-horizon pairs left out.

    Use ``rusinkiewicz_sweep`` to learn how many combinations were left out and which.
    """
    return rusinkiewicz_sweep(theta_h_deg, theta_d_deg, phi_d_deg, phi_h_deg).points


def _row_error(i: int, row: object) -> str | None:
    """What is wrong with row ``i`` (4 angles in degrees), or None if nothing is."""
    try:
        items = list(row)  # type: ignore[call-overload]
    except TypeError:
        return f"row {i}: {row!r} is not a sequence of 4 angles in degrees"
    if len(items) != 4:
        return f"row {i}: {len(items)} values {row!r}, expected 4 (theta_i, phi_i, theta_o, phi_o)"
    for name, item in zip(COLUMNS, items, strict=True):
        try:
            v = float(item)
        except (TypeError, ValueError):
            return f"row {i}: {name} = {item!r} is not a number (degrees)"
        if not math.isfinite(v):
            return f"row {i}: {name} = {v!r} is not a finite angle in degrees"
        if name.startswith("theta") and not 0.0 <= v <= 90.0:
            return f"row {i}: {name} = {v!r} deg, expected 0 <= {name} <= 90 deg"
    return None


def _validated(points_deg: Sequence[Sequence[float]] | FloatArray) -> FloatArray:
    """Rows as an (N, 4) float64 array; ValueError names the first bad row, column and value."""
    try:
        a: FloatArray | None = np.asarray(points_deg, dtype=np.float64)
    except (TypeError, ValueError):
        a = None  # ragged or not numeric: the row loop below names the culprit
    if a is not None and a.ndim == 2 and a.shape[1] == 4:
        theta = a[:, [0, 2]]
        good = np.isfinite(a).all(axis=1) & ((theta >= 0.0) & (theta <= 90.0)).all(axis=1)
        if good.all():
            return a.copy()
        bad = int(np.argmin(good))
        raise ValueError(_row_error(bad, a[bad].tolist()))
    if a is not None and a.size == 0:
        return np.empty((0, 4))
    for i, row in enumerate(points_deg):
        if (message := _row_error(i, row)) is not None:
            raise ValueError(message)
    shape = None if a is None else a.shape
    raise ValueError(f"points must form an (N, 4) array of angles in degrees, got shape {shape}")


def explicit(points_deg: Sequence[Sequence[float]]) -> FloatArray:
    """An explicit list of (theta_i, phi_i, theta_o, phi_o) rows in degrees, validated, as (N, 4).

    Raises ValueError naming the row index and the bad value (shape, finiteness, theta outside [0, 90]).
    """
    return _finish(_validated(points_deg))


def isotropic(points_deg: FloatArray) -> FloatArray:
    """Isotropic reduction of rows (N, 4) in degrees: phi_i = 0, phi_o folded into [0, 180], deduplicated.

    An isotropic BRDF depends on theta_i, theta_o and |phi_o - phi_i| only (rotation about the normal,
    then mirror symmetry about the plane of incidence), so each pair is turned about the normal until
    phi_i = 0 and phi_o -> phi_o - phi_i is folded into [0, 180]. At theta_i = 0 every phi_o is
    equivalent; it becomes 180 (the in-plane "opposite the light" side, where the four-axis rig's roll
    rests at 0). Order: first occurrence in the input.
    """
    p = normalise(_validated(points_deg))
    rel = np.mod(p[:, 3] - p[:, 1], 360.0)
    rel = np.where(rel > 180.0, 360.0 - rel, rel)
    rel = np.where(p[:, 0] == 0.0, 180.0, rel)
    return _finish(np.stack([p[:, 0], np.zeros(len(p)), p[:, 2], rel], axis=-1))
