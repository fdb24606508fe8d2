"""What the capture-mode benchmarks share (bench/image_mode, bench/continuous_scan): the rig, the cut at equal rig
time, the score against the truth and the honesty rule.

Each bench runs sweep_tradeoff's materials on the simulated rig in stop-and-go (the anchor) and in another mode,
cuts the other run in time order at the anchor's rig time, fits what is left with effective errors (each row
predicted as its model's mean over its footprint, ``model.fit.footprint``) and scores it against the true material;
``honest`` judges the fractions of readings within 1/2/3 standard errors of the truth's mean over each reading's
footprint (a tile's spread, a scan's blur): what the rig measures.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from analysis.batch.tradeoff import REFERENCE_SNR, Material
from model.fit.angular import angular_variance, fit_with_angular
from model.fit.design import ErrorPairs, brdf_error
from model.fit.footprint import footprint_average
from model.fit.samples import Samples
from rig.run.config.files import RigConfig, material_from, parse, rig_config
from rig.run.config.schema import RigFile
from rig.run.storage.store import RunStore

#: Stop-and-go's camera (pixels a side) and its 4 px ROI, sweep_tradeoff's.
POINT_RESOLUTION = 512
#: Goals of issue 30.
THROUGHPUT_GOAL = 100.0
ERROR_GOAL = 0.5
NOMINAL = (0.683, 0.954, 0.997)
#: Least tolerance on each "within k SE" fraction, however many readings (the binomial scatter may be larger).
TOLERANCE = (0.05, 0.02, 0.005)


def mode_rig(material: Material, seed: int, resolution: int, sample: dict[str, Any] | None = None,
             **tables: dict[str, Any]) -> RigConfig:  # fmt: skip
    """sweep_tradeoff's rig (``analysis.batch.tradeoff.rig_for``) on a camera of ``resolution`` px, a 4 px ROI.

    ``sample``: the ``[sample]`` table (None: the flat default); ``tables``: more tables merged in (``link``,
    ``simulation``).
    """
    c = resolution // 2
    doc: dict[str, Any] = {
        "name": "capture-mode bench rig",
        "simulation": {"material": material.table, "seed": seed},
        "camera": {"resolution": [resolution, resolution], "roi": [c - 2, c - 2, c + 2, c + 2]},
        "reference": {"every": 25, "target_snr": REFERENCE_SNR},
    }
    if sample is not None:
        doc["sample"] = sample
    for key, value in tables.items():
        doc[key] = {**doc.get(key, {}), **value}
    return rig_config(parse(doc, RigFile, "<capture-mode rig>"), "<capture-mode rig>")


def point_times(run: Path) -> dict[int, float]:
    """Each point's index and the run time (s) its reading ended at, from the run's journal."""
    return {int(r["index"]): float(r["run_time_s"]) for r in RunStore.read(run).records() if r["kind"] == "point"}


def cut_at(run: Path, rows: list[dict[str, Any]], rig_s: float) -> tuple[list[dict[str, Any]], int, float]:
    """The rows of the points ``run`` measured by run time ``rig_s`` (s); how many points, the last one's time (s)."""
    ends = point_times(run)
    kept_idx = {i for i, t in ends.items() if t <= rig_s}
    kept = [r for r in rows if int(r["index"]) in kept_idx]
    return kept, len(kept_idx), max((ends[i] for i in kept_idx), default=0.0)


def within(z: np.ndarray) -> list[float]:
    """Fractions of ``z`` (standard scores) within 1, 2 and 3."""
    return [float(np.mean(np.abs(z) <= k)) for k in (1, 2, 3)]


def score(rig: RigConfig, material: Material, rows: list[dict[str, Any]], pairs: ErrorPairs) -> dict[str, Any]:
    """Fit the rows with effective errors, score against the truth; the readings' z against the truth's mean over
    each reading's footprint.

    Keys: ``error`` and ``shape`` (relative BRDF errors, ``model.fit.design.brdf_error``), ``within_readings`` and
    ``within_footprint`` (fractions within 1/2/3 SE with the readings' errors alone and with the directions' angular
    variance at the true material added: footprint, and a scan's blur), ``n_z`` (readings scored).
    """
    samples = Samples.from_table_rows(rows, errors="point")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res, _ = fit_with_angular(material.spec, samples)
    truth = material_from(rig)
    exact = Samples.from_table_rows(rows, errors="readings")
    pred = footprint_average(truth, exact.wi, exact.wo, exact.direction_cov)
    footprint = angular_variance(truth, exact)
    keep = ~samples.lower_bound
    z_read = ((samples.value - pred) / exact.std_error)[keep].reshape(-1)
    z_foot = ((samples.value - pred) / np.sqrt(np.square(exact.std_error) + footprint))[keep].reshape(-1)
    return {"error": brdf_error(res.model, truth, pairs), "shape": brdf_error(res.model, truth, pairs, scale_free=True),
            "within_readings": within(z_read), "within_footprint": within(z_foot), "n_z": len(z_foot)}  # fmt: skip


def honest(fractions: list[float], n: int) -> bool:
    """Whether each fraction within 1/2/3 SE is its normal share, to the binomial scatter or TOLERANCE."""
    return all(abs(w - q) <= max(3.0 * math.sqrt(q * (1.0 - q) / max(n, 1)), tol)
               for w, q, tol in zip(fractions, NOMINAL, TOLERANCE, strict=True))  # fmt: skip


def pct(fractions: list[float]) -> str:
    """Fractions as percentages with one decimal, joined by slashes."""
    return "/".join(f"{100 * w:.1f}" for w in fractions)
