"""The run's tidy table of BRDF samples, computed from the journal alone.

Points are calibrated against the reference readings around them in the run's order: the reference taken
before a point and the next one after it, interpolated linearly in position (the run's drift correction);
the last points, with no reference after them, use the last one. Because the table is a function of the
journal, a run resumed after a crash ends with the table of an uninterrupted run.

Columns: the sweep index; measured and target BRDF angles (deg); the joint angles read back (deg); per
channel r, g, b: the BRDF (1/sr) with its standard error and the error without the reference albedo's
common part, and the raw reading (counts/s at gain 1) with its error; whether the value is a lower
bound (saturated pixels); whether the ROI was dark (no light detected even after metering: the value is
noise about zero); the frames and their total exposure (s).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from acquisition.calibration import ReferenceCalibration

CHANNELS = ("r", "g", "b")


def _calibration(
    ref: Mapping[str, Any], nxt: Mapping[str, Any] | None, albedo: Any, albedo_se: float
) -> ReferenceCalibration:
    cal = ReferenceCalibration(
        np.asarray(ref["reading"], dtype=float), np.asarray(ref["reading_std_error"], dtype=float),
        np.asarray(albedo, dtype=float), np.asarray(albedo_se, dtype=float), float(ref["theta_i_deg"]),
        float(ref["theta_o_deg"]), time_s=float(ref["slot"]), description="Lambertian reference",
    )  # fmt: skip
    if nxt is not None:
        cal = cal.with_closing_reading(
            np.asarray(nxt["reading"], dtype=float), np.asarray(nxt["reading_std_error"], dtype=float),
            time_s=float(nxt["slot"]),
        )  # fmt: skip
    return cal


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
    """Table rows (one per measured point, in sweep-index order) from journal records; see the module docstring."""
    refs = sorted((r for r in records if r.get("kind") == "reference"), key=lambda r: r["slot"])
    points = sorted((r for r in records if r.get("kind") == "point"), key=lambda r: r["index"])
    rows = []
    for p in points:
        pos = p["position"]
        before = [r for r in refs if r["slot"] <= pos]
        after = [r for r in refs if r["slot"] > pos]
        brdf = se = se_read = None
        lower = bool(p["lower_bound"])
        if before and albedo is not None:
            cal = _calibration(before[-1], after[0] if after else None, albedo, albedo_std_error)
            sample = cal.to_brdf(
                np.asarray(p["reading"], dtype=float), p["theta_i_deg"], p["theta_o_deg"],
                std_error=np.asarray(p["reading_std_error"], dtype=float),
                time_s=pos + 0.5 if after else None, include_cosine=include_cosine,
            )  # fmt: skip
            brdf, se, se_read = sample.value.tolist(), sample.std_error.tolist(), sample.std_error_readings.tolist()
        row: dict[str, Any] = {"index": p["index"]}
        for key in ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg"):
            row[key] = p[key]
        for key, value in zip(("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg"), p["target_deg"], strict=True):
            row[f"target_{key}"] = value
        for name in joint_names:
            row[f"{name}_deg"] = p["joints_deg"][name]
        row |= _channels("brdf", brdf) | _channels("brdf_se", se) | _channels("brdf_se_readings", se_read)
        row |= _channels("reading", p["reading"]) | _channels("reading_se", p["reading_std_error"])
        row["includes_cosine"] = include_cosine
        row["lower_bound"] = lower
        row["dark"] = bool(p.get("dark", False))  # journals before the flag existed: not known to be dark
        row["n_frames"] = len(p["exposures_s"])
        row["total_exposure_s"] = float(sum(p["exposures_s"]))
        row["exposures_s"] = ";".join(repr(float(t)) for t in p["exposures_s"])
        rows.append(row)
    return rows
