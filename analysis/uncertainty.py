"""How honest the errors are: the angular share of the error budget, and z-scores against the fit and the truth.

For each sample (and channel) the effective error is the photometric one plus the angular share
(``model.fit.angular``); z = (measured - predicted) / effective error, the prediction being the model's mean
over the sample's footprint where it has a direction covariance (``model.fit.footprint``: what a tile or a
blurred frame reads, and what the fit predicts). If the errors are right, the z of
independent samples are standard normal: 68.3 %, 95.4 % and 99.7 % of them within 1, 2 and 3. Against the
fitted model the z measure how well the model and the errors agree; against the truth (a simulated run's
material) they measure whether the error bars are honest. Lower-bound (saturated) samples are left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis.result import Analysis, Reference
from model.base import BRDF
from model.fit.footprint import footprint_average

FloatArray = npt.NDArray[np.float64]
NORMAL = {1: 0.6827, 2: 0.9545, 3: 0.9973}


@dataclass(frozen=True)
class ZSummary:
    """z-scores of the usable samples (flattened over channels) and the fractions within 1, 2, 3."""

    z: FloatArray
    within: dict[int, float]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: the fractions, the normal's, and their binomial scatter for this many z."""
        n = max(len(self.z), 1)
        return {
            "n": len(self.z),
            "within": {str(k): v for k, v in self.within.items()},
            "normal": {str(k): p for k, p in NORMAL.items()},
            "binomial_std": {str(k): math.sqrt(p * (1 - p) / n) for k, p in NORMAL.items()},
            "rms_z": float(np.sqrt(np.mean(self.z**2))) if len(self.z) else None,
        }


def z_scores(a: Analysis, brdf: BRDF, photometric_se: FloatArray | None = None) -> ZSummary:
    """z of every usable sample against ``brdf`` (its footprint mean) with the effective errors (photometric
    ``photometric_se`` if given, else the samples', plus the angular share)."""
    s = a.samples
    pred = footprint_average(brdf, s.wi, s.wo, s.direction_cov)
    pred = np.broadcast_to(pred, s.value.shape) if pred.shape[1] == 1 else pred
    se = a.effective_std_error() if photometric_se is None else np.sqrt(
        np.square(photometric_se) + (a.angular_variance if a.angular_variance is not None else 0.0))
    z = ((s.value - pred) / se)[~s.lower_bound].reshape(-1)
    z = z[np.isfinite(z)]
    within = {k: float(np.mean(np.abs(z) <= k)) if len(z) else math.nan for k in (1, 2, 3)}
    return ZSummary(z, within)


def truth(a: Analysis) -> Reference | None:
    """The simulated material of a simulated run (its true BRDF and the errors to judge it by), if any."""
    return next((r for r in a.references if r.label.endswith("(truth)")), None)


def angular_summary(a: Analysis) -> dict[str, Any]:
    """The angular share of the effective variance: in total and per sample (mean over channels)."""
    if a.angular_variance is None:
        return {"included": False}
    photometric = np.square(np.asarray(a.samples.std_error, dtype=np.float64))
    angular = np.asarray(a.angular_variance, dtype=np.float64)
    total = photometric + angular
    share = np.where(total > 0, angular / np.where(total > 0, total, 1.0), 0.0)
    return {
        "included": True,
        "share_total": float(angular.sum() / total.sum()) if total.sum() > 0 else 0.0,
        "share_median": float(np.median(share.mean(axis=1))),
        "share_max": float(share.max()),
        "share_per_sample": share.mean(axis=1).tolist(),
    }


def uncertainty_json(a: Analysis) -> dict[str, Any]:
    """The uncertainty section of fit.json: the angular share, and z against the fit (and the truth)."""
    out: dict[str, Any] = {"angular": angular_summary(a), "z_fit": z_scores(a, a.selection.chosen.model).as_dict()}
    true = truth(a)
    if true is not None:
        out["z_truth"] = z_scores(a, true.brdf, true.std_error).as_dict()
    return out
