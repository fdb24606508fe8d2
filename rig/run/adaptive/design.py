"""Where an adaptive sweep measures: the candidate pool, the space-filling first round, and the design's next points.

Candidates: cosine-distributed pairs (the diffuse body) plus Rusinkiewicz pairs with theta_h drawn
densely near 0 (the specular lobe, where a narrow peak hides between cosine-random points), all with
phi_i = 0 for isotropic samples and filtered by the rig's kinematics. The first round is a space-filling
pick over the candidates in (theta_h, theta_d, phi_d), since there is no fit to ask yet. Later rounds take
the candidates that most lower the fit's expected BRDF error over the hemisphere (``model.fit.design``);
in image mode a candidate is a capture of many samples, and its information is all of theirs.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from model.fit.design import (
    ErrorPairs,
    choose_batch,
    cosine_zeniths,
    covariance,
    error_weight,
    fisher,
    pooled,
    sensitivities,
)
from model.fit.samples import Samples
from model.fit.solve import FitResult
from model.fit.spec import FitSpec
from model.geometry import degrees_to_vector
from rig.instrument.kinematics import solve_degrees
from rig.run.adaptive.modes import Footprints
from rig.run.config.sweeps import directions_to_half_diff, half_diff_to_directions

FloatArray = npt.NDArray[np.float64]
#: Relative noise assumed where a fitted value is below this fraction of the median (keeps sigma > 0).
NOISE_FLOOR = 1e-3


def candidate_points(geometry: Any, n: int, *, max_theta_deg: float = 80.0, seed: int = 0) -> FloatArray:
    """Up to n reachable isotropic candidates (N, 4) in degrees: half cosine-random, half near-specular."""
    rng = np.random.default_rng(seed)
    m = n // 2
    ti, to = (cosine_zeniths(rng, n - m, max_theta_deg) for _ in range(2))
    body = np.stack([ti, np.zeros(n - m), to, rng.uniform(0.0, 180.0, n - m)], axis=-1)
    # theta_h = 90 u^2 puts half the lobe candidates within 22.5 deg of the mirror direction.
    hd = half_diff_to_directions(90.0 * rng.uniform(0, 1, m) ** 2, rng.uniform(0.0, max_theta_deg, m),
                                 rng.uniform(0.0, 180.0, m), rng.uniform(0.0, 360.0, m))  # fmt: skip
    # Turn each pair about the normal so that phi_i = 0: the same geometry for an isotropic sample.
    lobe = np.stack([hd[:, 0], np.zeros(m), hd[:, 2], (hd[:, 3] - hd[:, 1]) % 360.0], axis=-1)
    pts = np.concatenate([body, lobe])
    pts[:, 3] = np.where(pts[:, 3] > 180.0, 360.0 - pts[:, 3], pts[:, 3])  # mirror: isotropic
    ok = (pts[:, 0] <= max_theta_deg) & (pts[:, 2] <= max_theta_deg)
    pts = pts[ok]
    reach = solve_degrees(geometry, pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3]).reachable
    return pts[np.asarray(reach, dtype=bool)]


def space_filling(points_deg: FloatArray, k: int) -> npt.NDArray[np.intp]:
    """k indices of points spread over (theta_h, theta_d, phi_d) by farthest-point selection."""
    hd = directions_to_half_diff(points_deg)
    x = np.stack([hd[:, 0] / 90.0, hd[:, 1] / 90.0, np.abs(hd[:, 2]) / 180.0], axis=-1)
    picked = [int(np.argmin(hd[:, 0] + hd[:, 1]))]
    d = np.linalg.norm(x - x[picked[0]], axis=1)
    for _ in range(k - 1):
        j = int(np.argmax(d))
        picked.append(j)
        d = np.minimum(d, np.linalg.norm(x - x[j], axis=1))
    return np.asarray(picked, dtype=np.intp)


def _values(model: Any, wi: npt.NDArray[np.floating], wo: npt.NDArray[np.floating], channels: int) -> FloatArray:
    f = np.asarray(model.eval(wi, wo), dtype=np.float64).reshape(len(wi), -1)
    return np.broadcast_to(f, (len(wi), channels))


def next_points(
    result: FitResult, spec: FitSpec, samples: Samples, pool: FloatArray, k: int, pairs: ErrorPairs,
    *, rel: float | None = None, cells: Footprints | None = None,
) -> tuple[npt.NDArray[np.intp], float, float]:  # fmt: skip
    """Indices of the k pool points to measure next, the predicted error now and after them (relative RMS).

    ``samples`` carry the errors the fit weighted them by. ``rel``: the relative noise of one sample of the next
    round (None: the median of ``samples``'). ``cells``: each pool capture's image-mode samples (``owner``
    indexes ``pool``), the information of all of them counted per capture (``model.fit.design.pooled``); None:
    each capture one sample at its directions (point mode).
    """
    c = samples.channels
    if rel is None:
        rel = float(np.median(samples.std_error / np.maximum(np.abs(samples.value), 1e-300)))

    def sigma(f: FloatArray) -> FloatArray:
        return rel * np.maximum(np.abs(f), NOISE_FLOOR * float(np.median(np.abs(f))) + 1e-300)

    x = result.values
    g_meas = sensitivities(spec, x, samples.wi, samples.wo, c)
    cov = covariance(fisher(g_meas, samples.std_error))
    a = error_weight(sensitivities(spec, x, pairs.wi, pairs.wo, c), _values(result.model, pairs.wi, pairs.wo, c))
    at = pool if cells is None else cells.angles_deg
    wi, wo = degrees_to_vector(at[:, 0], at[:, 1]), degrees_to_vector(at[:, 2], at[:, 3])
    g = sensitivities(spec, x, wi, wo, c)
    noise: npt.NDArray[np.floating] = sigma(_values(result.model, wi, wo, c))
    if cells is not None:
        # A cell stands for cells.tiles tiles at its directions: that many readings' information.
        g, noise = pooled(g, noise / np.sqrt(cells.tiles)[:, None], cells.owner, len(pool))
    batch = choose_batch(cov, g, noise, a, k)
    return batch.indices, batch.error_before, float(batch.error_after[-1])
