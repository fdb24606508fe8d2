"""The run's tidy table of BRDF samples, computed from the journal alone.

Points are calibrated against the reference readings around them in the run's order: the reference taken
before a point and the next one after it, interpolated linearly in time (the run's drift correction: a lamp
drifts with time, and points are not evenly spaced in time when moves differ in length); the last points,
with no reference after them, use the last one. Time is each reading's ``reading_time_s`` (run time at the
middle of its exposures); journals written before readings carried it are interpolated in position.
Because the table is a function of the
journal, a run resumed after a crash ends with the table of an uninterrupted run.

Columns: the sweep index; measured and target BRDF angles (deg); the joint angles read back (deg); per
channel r, g, b: the BRDF (1/sr) with its standard error and the error without the reference albedo's
common part, and the raw reading (counts/s at gain 1) with its error; whether the value is a lower
bound (saturated pixels); whether the ROI was dark (no light detected even after metering: the value is
noise about zero); the frames, their total exposure (s) and each one's (a JSON array, s); the standard
uncertainty of the measured angles (``theta_i_std_deg`` ... ``phi_o_std_deg``, deg) and the covariance of the
local directions' tangent components (``direction_cov``, a JSON 4 x 4 over wi_x, wi_y, wo_x, wo_y; see
``rig.instrument.direction_uncertainty``), empty for journals written before points carried them; the UTC time
the point was recorded (``utc``, ISO 8601). Units and meanings of every column: ``rig.run.tables.parquet.column``
(and the table's ``samples.schema.json``).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from acquisition.calibration import ReferenceCalibration

CHANNELS = ("r", "g", "b")


def _times(point: Mapping[str, Any], ref: Mapping[str, Any], nxt: Mapping[str, Any] | None) -> tuple[float, ...]:
    """(reference, closing reference, point) times: reading times where all have one, else positions."""
    used = [point, ref] + ([nxt] if nxt is not None else [])
    if all("reading_time_s" in r for r in used):
        t = (float(ref["reading_time_s"]), float(nxt["reading_time_s"]) if nxt else math.nan,
             float(point["reading_time_s"]))  # fmt: skip
        if nxt is None or t[0] < t[1]:
            return t
    return float(ref["slot"]), float(nxt["slot"]) if nxt else math.nan, point["position"] + 0.5


def _calibration(
    ref: Mapping[str, Any], nxt: Mapping[str, Any] | None, albedo: Any, albedo_se: float, times: tuple[float, ...]
) -> ReferenceCalibration:
    cal = ReferenceCalibration(
        np.asarray(ref["reading"], dtype=float), np.asarray(ref["reading_std_error"], dtype=float),
        np.asarray(albedo, dtype=float), np.asarray(albedo_se, dtype=float), float(ref["theta_i_deg"]),
        float(ref["theta_o_deg"]), time_s=times[0], description="Lambertian reference",
        light_distance_m=ref.get("light_distance_m"),
    )  # fmt: skip
    if nxt is not None:
        cal = cal.with_closing_reading(
            np.asarray(nxt["reading"], dtype=float), np.asarray(nxt["reading_std_error"], dtype=float),
            time_s=times[1],
        )  # fmt: skip
    return cal


ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")


def _direction_columns(p: Mapping[str, Any]) -> dict[str, Any]:
    """The angles' standard uncertainties (deg) and the directions' tangent covariance (JSON) of a point."""
    if "angle_cov_deg2" not in p:
        return {f"{a}_std_deg": None for a in ANGLES} | {"direction_cov": None}
    var = np.diag(np.asarray(p["angle_cov_deg2"], dtype=float))
    out: dict[str, Any] = {f"{a}_std_deg": float(np.sqrt(max(v, 0.0))) for a, v in zip(ANGLES, var, strict=True)}
    out["direction_cov"] = json.dumps(p["direction_cov"], separators=(",", ":"))
    return out


def _channels(prefix: str, values: Sequence[float] | None) -> dict[str, Any]:
    if values is None:
        return {f"{prefix}_{c}": None for c in CHANNELS}
    v = list(values) * 3 if len(values) == 1 else list(values)
    return {f"{prefix}_{c}": float(x) for c, x in zip(CHANNELS, v, strict=True)}


def build_rows(
    records: Sequence[Mapping[str, Any]],
    joint_names: Sequence[str],
    *,
    albedo: Any = None,
    albedo_std_error: float = 0.0,
    include_cosine: bool = False,
) -> list[dict[str, Any]]:
    """Table rows (one per measured point, in sweep-index order) from journal records; see the module docstring.

    An image-mode point (a record with ``tiles``) gives one row per tile, in tile order, with a ``tile`` column.
    """
    refs = sorted((r for r in records if r.get("kind") == "reference"), key=lambda r: r["slot"])
    points = sorted((r for r in records if r.get("kind") == "point"), key=lambda r: r["index"])
    rows = []
    for p in points:
        pos = p["position"]
        before = [r for r in refs if r["slot"] <= pos]
        after = [r for r in refs if r["slot"] > pos]
        cal: ReferenceCalibration | None = None
        t = None
        if before and albedo is not None:
            nxt = after[0] if after else None
            times = _times(p, before[-1], nxt)
            cal = _calibration(before[-1], nxt, albedo, albedo_std_error, times)
            # Readings in the middle of the references' own exposures are clipped into their span.
            t = min(max(times[2], times[0]), times[1]) if nxt is not None else None
        for sample in _samples(p):
            rows.append(_row(p, sample, joint_names, cal, t, include_cosine))
    return rows


def _samples(p: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """The samples of a point record: itself, or (image mode) each of its tiles with the point's pose errors added."""
    tiles = p.get("tiles")
    if tiles is None:
        return [p]
    out: list[Mapping[str, Any]] = []
    pose_a = np.asarray(p.get("angle_cov_deg2", np.zeros((4, 4))), dtype=float).reshape(16)
    pose_t = np.asarray(p.get("direction_cov", np.zeros((4, 4))), dtype=float).reshape(16)
    for k in range(len(tiles["tile"])):
        tile = {key: tiles[key][k] for key in tiles}
        # A tile's directions carry its footprint's spread and the pose's own error (common to every tile).
        tile["angle_cov_deg2"] = (np.asarray(tile["angle_cov_deg2"]) + pose_a).reshape(4, 4).tolist()
        tile["direction_cov"] = np.round((np.asarray(tile["direction_cov"]) + pose_t), 18).reshape(4, 4).tolist()
        out.append(tile)
    return out


def _row(
    p: Mapping[str, Any],
    s: Mapping[str, Any],
    joint_names: Sequence[str],
    cal: ReferenceCalibration | None,
    t: float | None,
    include_cosine: bool,
) -> dict[str, Any]:
    """One row: the point ``p``'s sample ``s`` (``p`` itself, or one of its tiles)."""
    brdf = se = se_read = None
    if cal is not None:
        sample = cal.to_brdf(
            np.asarray(s["reading"], dtype=float), s["theta_i_deg"], s["theta_o_deg"],
            std_error=np.asarray(s["reading_std_error"], dtype=float),
            time_s=t, include_cosine=include_cosine,
            light_distance_m=s.get("light_distance_m") if cal.light_distance_m is not None else None,
        )  # fmt: skip
        brdf, se, se_read = sample.value.tolist(), sample.std_error.tolist(), sample.std_error_readings.tolist()
    row: dict[str, Any] = {"index": p["index"]}
    if s is not p:
        row["tile"] = s["tile"]
    for key in ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg"):
        row[key] = s[key]
    for key, value in zip(("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg"), p["target_deg"], strict=True):
        row[f"target_{key}"] = value
    for name in joint_names:
        row[f"{name}_deg"] = p["joints_deg"][name]
    row |= _channels("brdf", brdf) | _channels("brdf_se", se) | _channels("brdf_se_readings", se_read)
    row |= _channels("reading", s["reading"]) | _channels("reading_se", s["reading_std_error"])
    row["includes_cosine"] = include_cosine
    row["lower_bound"] = bool(s["lower_bound"])
    row["dark"] = bool(s.get("dark", False))  # journals before the flag existed: not known to be dark
    row["n_frames"] = len(p["exposures_s"])
    row["total_exposure_s"] = float(sum(p["exposures_s"]))
    # A JSON array: one cell that any CSV reader keeps whole and json.loads turns into a list.
    row["exposures_s"] = json.dumps([float(t) for t in p["exposures_s"]])
    row |= _direction_columns(s)
    row["utc"] = p.get("utc")
    return row
