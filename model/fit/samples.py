"""BRDF samples to fit: directions, values per channel, their standard errors and lower-bound flags.

``Samples`` is what :func:`model.fit.fit` consumes. It reads a run's table (angles in degrees, the
column names of rig/run/tables/samples.py) or subsamples a MERL table. Problems with the data that would make a fit
silently wrong raise :class:`FitError` naming the sample; problems a fit can work around (rows without
a value, directions below the horizon) drop the rows and leave a note that the fit repeats as a warning.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from model.errors import InputError
from model.geometry import degrees_to_vector, from_half_diff
from model.merl import MerlTable, bin_centers

Array = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
CHANNELS = ("r", "g", "b")


class FitError(InputError, ValueError):
    """The data cannot support the requested fit (too few samples, invalid uncertainties, degeneracy)."""


def _num(v: Any) -> float:
    if v is None or (isinstance(v, str) and v.strip() == ""):
        return float("nan")
    return float(v)


def _flag(v: Any) -> bool:
    if isinstance(v, str):
        return v.strip().lower() in ("true", "1", "yes")
    return bool(v)


def _direction_cov(rows: Sequence[Mapping[str, Any]], source: str) -> Array | None:
    """The rows' ``direction_cov`` (a JSON 4 x 4 each, see rig/run/tables/samples.py), None unless every row has one."""
    cells = [r.get("direction_cov") for r in rows]
    if any(c is None or (isinstance(c, str) and not c.strip()) for c in cells):
        return None
    try:
        out = np.array([json.loads(c) if isinstance(c, str) else c for c in cells], dtype=np.float64)
    except (ValueError, TypeError) as exc:
        raise FitError(f"{source or 'table'}: direction_cov is not a 4 x 4 matrix of numbers in every row: "
                       f"{exc}") from None  # fmt: skip
    if out.shape != (len(rows), 4, 4):
        raise FitError(f"{source or 'table'}: direction_cov: expected a 4 x 4 matrix per row, got shape "
                       f"{out.shape[1:]}")  # fmt: skip
    return out


@dataclass(frozen=True, eq=False)
class Samples:
    """N BRDF samples: wi, wo (N, 3) unit vectors in the local frame; value, std_error (N, C) in 1/sr.

    ``lower_bound`` (N,) marks saturated readings, whose value is only a lower bound; the fit leaves them
    out. ``std_error_assumed`` says the errors are an assumption (MERL files carry none), not measured.
    ``direction_cov`` (N, 4, 4), when measured, is the covariance of each pair's directions (tangent
    components wi_x, wi_y, wo_x, wo_y; see :mod:`model.fit.angular`); empty (0, 4, 4) when unknown.
    Every sample that is not a lower bound must have a finite value and a positive, finite std_error.
    """

    wi: Array
    wo: Array
    value: Array
    std_error: Array
    lower_bound: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    std_error_assumed: bool = False
    notes: tuple[str, ...] = ()
    source: str = ""
    direction_cov: Array = field(default_factory=lambda: np.zeros((0, 4, 4)))

    def __post_init__(self) -> None:
        wi = np.asarray(self.wi, dtype=np.float64)
        wo = np.asarray(self.wo, dtype=np.float64)
        if wi.ndim != 2 or wi.shape[1] != 3 or wo.shape != wi.shape:
            raise FitError(f"wi and wo must both have shape (N, 3); got {wi.shape} and {wo.shape}")
        n = wi.shape[0]
        value = np.asarray(self.value, dtype=np.float64)
        value = value[:, None] if value.ndim == 1 else value
        if value.ndim != 2 or value.shape[0] != n:
            raise FitError(f"value must have shape (N,) or (N, C) with N = {n}; got {np.shape(self.value)}")
        try:
            se = np.broadcast_to(np.asarray(self.std_error, dtype=np.float64).reshape(n, -1), value.shape).copy()
        except ValueError:
            raise FitError(f"std_error shape {np.shape(self.std_error)} does not match value {value.shape}") from None
        lower = np.asarray(self.lower_bound, dtype=bool)
        lower = np.zeros(n, dtype=bool) if lower.size == 0 else lower.reshape(-1)
        if lower.shape != (n,):
            raise FitError(f"lower_bound must have shape ({n},); got {lower.shape}")
        used = ~lower
        bad_value = used[:, None] & ~np.isfinite(value)
        if bad_value.any():
            i, c = np.argwhere(bad_value)[0]
            raise FitError(f"sample {i}: value {value[i, c]!r} in channel {c} is not finite")
        # A zero or negative error would give a sample infinite (or imaginary) weight: refuse, naming it.
        bad_se = used[:, None] & ~(np.isfinite(se) & (se > 0))
        if bad_se.any():
            i, c = np.argwhere(bad_se)[0]
            raise FitError(
                f"sample {i}: std_error {se[i, c]!r} in channel {c} must be positive and finite "
                f"({int(bad_se.any(axis=1).sum())} samples affected); zero-variance samples would get infinite weight"
            )
        cov = np.asarray(self.direction_cov, dtype=np.float64)
        if cov.size and cov.shape != (n, 4, 4):
            raise FitError(f"direction_cov must have shape ({n}, 4, 4) or be empty; got {cov.shape}")
        if cov.size and not np.all(np.isfinite(cov)):
            i = int(np.argwhere(~np.isfinite(cov))[0][0])
            raise FitError(f"sample {i}: direction_cov is not finite")
        cov = cov if cov.size else np.zeros((0, 4, 4))
        for name, arr in (("wi", wi), ("wo", wo), ("value", value), ("std_error", se), ("lower_bound", lower),
                          ("direction_cov", cov)):  # fmt: skip
            object.__setattr__(self, name, arr)

    @property
    def n(self) -> int:
        """Number of samples N."""
        return int(self.wi.shape[0])

    @property
    def channels(self) -> int:
        """Number of channels C."""
        return int(self.value.shape[1])

    def subset(self, mask: npt.ArrayLike, note: str | None = None) -> Samples:
        """The samples where mask (N,) is true (or at the given indices), with an optional note added."""
        m = np.asarray(mask)
        notes = self.notes if note is None else (*self.notes, note)
        return Samples(
            self.wi[m], self.wo[m], self.value[m], self.std_error[m], self.lower_bound[m],
            self.std_error_assumed, notes, self.source,
            self.direction_cov[m] if self.direction_cov.size else np.zeros((0, 4, 4)),
        )  # fmt: skip

    @classmethod
    def from_arrays(
        cls,
        theta_i_deg: npt.ArrayLike,
        phi_i_deg: npt.ArrayLike,
        theta_o_deg: npt.ArrayLike,
        phi_o_deg: npt.ArrayLike,
        value: npt.ArrayLike,
        std_error: npt.ArrayLike,
        lower_bound: npt.ArrayLike | None = None,
        *,
        includes_cosine: bool | npt.ArrayLike = False,
        source: str = "",
        direction_cov: npt.ArrayLike | None = None,
    ) -> Samples:
        """Samples from angles in degrees, values in 1/sr; rows below the horizon are dropped with a note."""
        wi = degrees_to_vector(theta_i_deg, phi_i_deg).reshape(-1, 3)
        wo = degrees_to_vector(theta_o_deg, phi_o_deg).reshape(-1, 3)
        n = wi.shape[0]
        v = np.asarray(value, dtype=np.float64).reshape(n, -1)
        se = np.broadcast_to(np.asarray(std_error, dtype=np.float64).reshape(n, -1), v.shape)
        lower = np.zeros(n, dtype=bool) if lower_bound is None else np.asarray(lower_bound, dtype=bool).reshape(n)
        with_cos = np.broadcast_to(np.asarray(includes_cosine, dtype=bool), (n,))
        # The calibration multiplies by cos(theta_i) when asked to include the cosine: undo it, since the
        # models' eval excludes it (docs/architecture.md, Conventions). Below the horizon the row is dropped anyway.
        cos_i = np.where(with_cos, np.maximum(wi[:, 2], 1e-300), 1.0)[:, None]
        v, se = v / cos_i, se / cos_i
        notes: list[str] = []
        below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
        missing = ~lower & ~np.all(np.isfinite(v), axis=1)
        if below.any():
            notes.append(f"{int(below.sum())} samples at or below the horizon dropped")
        if (missing & ~below).any():
            notes.append(f"{int((missing & ~below).sum())} samples without a BRDF value (no calibration) dropped")
        keep = ~below & ~missing
        cov = None if direction_cov is None else np.asarray(direction_cov, dtype=np.float64).reshape(n, 4, 4)[keep]
        return cls(wi[keep], wo[keep], v[keep], se[keep], lower[keep], False, tuple(notes), source,
                   np.zeros((0, 4, 4)) if cov is None else cov)  # fmt: skip

    @classmethod
    def from_table_rows(
        cls, rows: Sequence[Mapping[str, Any]], source: str = "", *, errors: str = "total"
    ) -> Samples:
        """Samples from a run table's rows (rig/run/tables/samples.py columns, degrees; CSV strings accepted).

        ``errors``: "total" takes ``brdf_se_*`` (the point's reading, the references' and the tile albedo's
        errors); "point" takes the point's own reading error only (``reading_se / reading`` times the BRDF);
        "readings" takes ``brdf_se_readings_*`` (the point's and the references' readings, not the albedo:
        what a simulated run, whose tile's albedo is exact, is judged by against its truth).
        The calibration's share is common to every point between two references (the albedo's to the whole
        run): it moves all values together, so it says nothing about a lobe's shape, and counted per point
        it drowns the difference between a capture at SNR 300 and one at SNR 100 and pushes chi2/dof far
        below 1. Fit with "point" to weight captures by what they measured; the scale is then uncertain by
        the calibration's error on top of the fit's.
        """
        if errors not in ("total", "point", "readings"):
            raise FitError(f"{source or 'table'}: errors = {errors!r}: expected 'total', 'point' or 'readings'")
        if not rows:
            raise FitError(f"{source or 'table'}: no rows to fit")
        chans = [c for c in CHANNELS if f"brdf_{c}" in rows[0]]
        if not chans:
            raise FitError(f"{source or 'table'}: no brdf_r/g/b columns; columns are {sorted(rows[0])}")
        cols = {k: np.array([_num(r.get(k)) for r in rows]) for k in
                ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")}  # fmt: skip
        value = np.stack([[_num(r.get(f"brdf_{c}")) for r in rows] for c in chans], axis=-1)
        column = "brdf_se_readings" if errors == "readings" else "brdf_se"
        if errors == "readings" and (missing := [f"{column}_{c}" for c in chans if f"{column}_{c}" not in rows[0]]):
            raise FitError(f"{source or 'table'}: errors = 'readings' needs the columns {missing} (tables written "
                           "before they were added have only brdf_se_*: use errors='total')")  # fmt: skip
        se = np.stack([[_num(r.get(f"{column}_{c}")) for r in rows] for c in chans], axis=-1)
        if errors == "point":
            missing = [k for c in chans for k in (f"reading_{c}", f"reading_se_{c}") if k not in rows[0]]
            if missing:
                raise FitError(f"{source or 'table'}: errors = 'point' needs the columns {missing}")
            reading = np.stack([[_num(r.get(f"reading_{c}")) for r in rows] for c in chans], axis=-1)
            reading_se = np.stack([[_num(r.get(f"reading_se_{c}")) for r in rows] for c in chans], axis=-1)
            with np.errstate(divide="ignore", invalid="ignore"):
                # A zero reading has a zero BRDF, and then the calibration's terms (relative, times the value)
                # vanish: its total error is its own, exactly.
                se = np.where(reading != 0, np.abs(value) * reading_se / np.abs(reading), se)
        lower = np.array([_flag(r.get("lower_bound", False)) for r in rows])
        with_cos = np.array([_flag(r.get("includes_cosine", False)) for r in rows])
        return cls.from_arrays(
            cols["theta_i_deg"], cols["phi_i_deg"], cols["theta_o_deg"], cols["phi_o_deg"], value, se, lower,
            includes_cosine=with_cos, source=source, direction_cov=_direction_cov(rows, source),
        )  # fmt: skip

    @classmethod
    def from_csv(cls, path: str | os.PathLike[str]) -> Samples:
        """Samples from a run's samples.csv (see rig/run/tables/samples.py for the columns)."""
        with open(path, encoding="utf-8", newline="") as fh:
            rows = list(csv.DictReader(fh))
        return cls.from_table_rows(rows, source=str(path))

    @classmethod
    def from_merl(
        cls, table: MerlTable, n: int | None, seed: int | np.random.Generator = 0, *, relative_error: float = 0.05
    ) -> Samples:
        """n samples at random MERL bin centres (random phi_h), RGB in 1/sr, with an assumed relative error.

        ``n=None`` takes every bin with data whose centre lies above the horizon (1,096,216 of the 1,458,000
        when every bin holds data), each once, at phi_h = 0 and with the bin's own value: the table is
        isotropic (its value does not depend on phi_h), and phi_h does not change whether a pair is above
        the horizon. A model with azimuthal structure (anisotropic Ward) then sees one azimuth only and its
        second slope is left unconstrained; draw n samples (random phi_h) for such models.
        MERL files carry no uncertainties; ``relative_error`` (dimensionless) times the value, floored at
        relative_error times the median value, stands in for them and the result says it is assumed.
        """
        if (n is not None and n < 1) or relative_error <= 0:
            raise FitError(f"from_merl: need n >= 1 (or None) and relative_error > 0; got n = {n}, {relative_error}")
        th, td, pd = (a.reshape(-1) for a in bin_centers())
        if n is None:
            # Bin centres map to their own bins, so the values are read by index, not looked up again.
            every = np.asarray(table.values, dtype=np.float64).reshape(table.channels, -1).T
            filled = np.flatnonzero(np.all(np.isfinite(every), axis=1))
            wi, wo = from_half_diff(th[filled], 0.0, td[filled], pd[filled])
            up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
            wi_all, wo_all = np.asarray(wi[up], dtype=np.float64), np.asarray(wo[up], dtype=np.float64)
            value = every[filled[up]]
            if wi_all.shape[0] == 0:
                raise FitError("from_merl: the table has no bins with data above the horizon")
        else:
            rng = np.random.default_rng(seed)
            wi_all, wo_all = np.empty((0, 3)), np.empty((0, 3))
            # Bins whose directions fall below the horizon or hold no data are rejected; draw until n remain.
            for _ in range(20):
                idx = rng.integers(0, th.size, size=4 * n)
                wi, wo = from_half_diff(th[idx], rng.uniform(0, 2 * np.pi, idx.size), td[idx], pd[idx])
                ok = (wi[:, 2] > 0) & (wo[:, 2] > 0) & table.has_data(wi, wo)
                wi_all, wo_all = np.concatenate([wi_all, wi[ok]]), np.concatenate([wo_all, wo[ok]])
                if wi_all.shape[0] >= n:
                    break
            if wi_all.shape[0] < n:
                raise FitError(f"from_merl: only {wi_all.shape[0]} bins with data above the horizon; asked for {n}")
            wi_all, wo_all = wi_all[:n], wo_all[:n]
            value = np.asarray(table.eval(wi_all, wo_all), dtype=np.float64)
        floor = relative_error * float(np.median(np.abs(value)))
        se = np.maximum(relative_error * np.abs(value), max(floor, 1e-12))
        note = f"std errors assumed: {relative_error:g} x value (MERL tables carry no uncertainties)"
        lower = np.zeros(wi_all.shape[0], dtype=bool)
        return cls(wi_all, wo_all, value, se, lower, True, (note,), table.source or "MERL")
