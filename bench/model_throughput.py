"""Evaluations per second of a GGX conductor, numpy in and numpy out: our numpy path, our kernel, Mitsuba.

CookTorrance with GGX, exact separable Smith masking and conductor Fresnel (aluminium, RGB eta and k,
alpha 0.3) on random direction pairs (N, 3) float64, output (N, 3); against Mitsuba 3's
``roughconductor`` with the same parameters in ``llvm_ad_rgb`` (the anchor: vectorised, JIT-compiled,
float32) and ``scalar_rgb`` (one Python call per pair, the only way to drive it from numpy).
The Mitsuba timings include the numpy -> drjit -> numpy conversions; one more row times Mitsuba's
evaluation alone (drjit arrays in and out) to show what those conversions cost. The kernel and
Mitsuba llvm are timed in alternating blocks (see :func:`block_medians`), so load from the rest of
the machine hits both. numba uses its default thread count, one per core.

Run: ``.venv/bin/python -m bench.model_throughput [--pairs N] [--repeats R]``.
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import drjit as dr
import mitsuba as mi
import numba
import numpy as np
import numpy.typing as npt

from bench._common import format_table, machine_description, median_time, uniform_hemisphere
from model import kernels
from model.base import Model
from model.cook_torrance import CookTorrance
from model.mitsuba.variant import unavailable_reason, use_variant

Array = npt.NDArray[np.floating]

ALPHA = 0.3
ALUMINIUM_ETA = (1.657, 0.880, 0.521)
ALUMINIUM_K = (9.224, 6.270, 4.837)
N_PAIRS = 1_000_000
N_SCALAR = 20_000
REPEATS = 9
ROUNDS = 3
LLVM, SCALAR = "llvm_ad_rgb", "scalar_rgb"
NUMPY = "ours: numpy reference (Model.eval)"
KERNEL = "ours: kernel float64 (CookTorrance.eval)"
ANCHOR = f"Mitsuba {LLVM} (anchor)"
KERNEL32 = "ours: kernel float32"
EVAL_ONLY = f"Mitsuba {LLVM}, drjit in and out"
SCALAR_LOOP = f"Mitsuba {SCALAR}, Python loop"
ORDER = (NUMPY, KERNEL, KERNEL32, ANCHOR, EVAL_ONLY, SCALAR_LOOP)


def _bsdf() -> Any:
    return mi.load_dict({
        "type": "roughconductor", "distribution": "ggx", "alpha": ALPHA, "sample_visible": False,
        "eta": {"type": "rgb", "value": list(ALUMINIUM_ETA)},
        "k": {"type": "rgb", "value": list(ALUMINIUM_K)},
    })


def mitsuba_llvm_eval(bsdf: Any, wi: Array, wo: Array) -> Array:
    """f_r cos(theta_o) in 1/sr of a Mitsuba BSDF in a jit variant, all pairs in one call, (N, 3) float32."""
    si = dr.zeros(mi.SurfaceInteraction3f)
    # Column by column: drjit casts to float32 itself, faster than a transposed numpy copy (2.9 vs 3.6 ms).
    si.wi = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
    f = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2]))
    return np.array(f).T  # drjit gives (3, N); the transpose is a view


def mitsuba_llvm_eval_only(bsdf: Any, si: Any, wo: Any) -> Any:
    """The same from drjit inputs to a drjit result: Mitsuba's own cost, without numpy conversions."""
    f = bsdf.eval(mi.BSDFContext(), si, wo)
    dr.eval(f)
    dr.sync_thread()  # evaluation is asynchronous in the llvm backend
    return f


def mitsuba_scalar_eval(bsdf: Any, wi: Array, wo: Array) -> Array:
    """The same in a scalar variant: one BSDF call per pair from Python."""
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    out = np.empty((len(wi), 3), dtype=np.float32)
    for n, (a, b) in enumerate(zip(wi.tolist(), wo.tolist(), strict=True)):
        si.wi = mi.Vector3f(a)
        out[n] = bsdf.eval(ctx, si, mi.Vector3f(b))
    return out


def block_medians(fns: dict[str, Callable[[], object]], rounds: int, per_block: int) -> dict[str, float]:
    """Median wall-clock seconds of each fn over ``rounds`` rounds of ``per_block`` timed calls.

    Each round times every fn in turn, so a change in the machine's load hits all of them; each block
    starts with an untimed call because numba's OpenMP threads and drjit's pool spin for a while after
    a call and roughly halve the speed of the other library's next call (measured: 8 -> 18 ms).
    """
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            fn()
            for _ in range(per_block):
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)
    return {name: statistics.median(ts) for name, ts in times.items()}


def measure(n: int, repeats: int) -> tuple[dict[str, tuple[int, float]], dict[str, str]]:
    """(pairs, median seconds) per path, and why each unavailable Mitsuba variant does not load."""
    rng = np.random.default_rng(2024)
    # Directions representable in float32, so Mitsuba and our float64 code see the very same pairs.
    wi = uniform_hemisphere(rng, n, np.float32).astype(np.float64)
    wo = uniform_hemisphere(rng, n, np.float32).astype(np.float64)
    model = CookTorrance(alpha=ALPHA, eta=ALUMINIUM_ETA, k=ALUMINIUM_K)
    kernels.warm_up(channels=3)
    fast: dict[str, Callable[[], object]] = {
        KERNEL: partial(model.eval, wi, wo),
        KERNEL32: partial(model.eval, wi.astype(np.float32), wo.astype(np.float32)),
    }
    per_block = max(1, repeats // ROUNDS)
    unavailable = {name: r for name in (LLVM, SCALAR) if (r := unavailable_reason(name)) is not None}
    ours, ref = model.eval(wi, wo), Model.eval(model, wi, wo)
    accuracy = [f"kernel float64 vs numpy reference: max relative difference {_max_rel(ours, ref):.2e}, "
                f"bit-identical {100 * np.mean(ours == ref):.2f} % of values"]
    if LLVM in unavailable:
        seconds = block_medians(fast, ROUNDS, per_block)
    else:
        with use_variant(LLVM):
            bsdf = _bsdf()
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi, wo_dr = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2]), mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])
            seconds = block_medians({
                **fast, ANCHOR: partial(mitsuba_llvm_eval, bsdf, wi, wo),
                EVAL_ONLY: partial(mitsuba_llvm_eval_only, bsdf, si, wo_dr),
            }, ROUNDS, per_block)
            f_mitsuba = mitsuba_llvm_eval(bsdf, wi, wo).astype(np.float64)
        # Mitsuba's eval includes the cosine foreshortening of the outgoing direction.
        accuracy.append(f"kernel * cos(theta_o) vs Mitsuba {LLVM} (float32): max relative difference "
                        f"{_max_rel(f_mitsuba, ours * wo[:, 2:3]):.2e}")
    result = {name: (n, s) for name, s in seconds.items()}
    result[NUMPY] = (n, median_time(partial(Model.eval, model, wi, wo), max(1, repeats // 3)))
    if SCALAR not in unavailable:
        m = min(n, N_SCALAR)
        with use_variant(SCALAR):
            result[SCALAR_LOOP] = (
                m, median_time(partial(mitsuba_scalar_eval, _bsdf(), wi[:m], wo[:m]), 3))
    print("\n".join(accuracy))
    return result, unavailable


def main(argv: list[str] | None = None) -> None:
    """Print the machine, the throughput table (ratios to Mitsuba llvm) and the accuracy figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=N_PAIRS, help="direction pairs per call")
    parser.add_argument("--repeats", type=int, default=REPEATS, help="timed calls per fast path")
    args = parser.parse_args(argv)
    print("# CookTorrance GGX, exact Smith, aluminium conductor (RGB), alpha 0.3: evaluations per second")
    print(f"date: {datetime.date.today().isoformat()}; {args.pairs} random pairs, numpy (N, 3) in and out")
    print(f"machine: {machine_description()}; numba {numba.__version__} with {numba.get_num_threads()} "
          f"threads, Mitsuba {mi.__version__}")
    result, unavailable = measure(args.pairs, args.repeats)
    anchor = result[ANCHOR][0] / result[ANCHOR][1] if ANCHOR in result else None
    rows = []
    for name in (name for name in ORDER if name in result):
        pairs, s = result[name]
        rate = pairs / s
        ratio = f"{rate / anchor:.3g}" if anchor is not None else "n/a"
        rows.append([name, f"{pairs:,}", f"{s:.3g}", f"{rate / 1e6:.3g}", ratio])
    rows += [[f"Mitsuba {name}", "-", "-", "unavailable", "-"] for name in unavailable]
    print(format_table(["path", "pairs", "median s", "M evals/s", "vs Mitsuba llvm"], rows))
    for name, reason in unavailable.items():
        print(f"Mitsuba {name} unavailable: {reason}")
    print(f"median of {ROUNDS * max(1, args.repeats // ROUNDS)} calls for the kernel and Mitsuba llvm, "
          f"{max(1, args.repeats // 3)} for the numpy path, 3 for Mitsuba scalar")


def _max_rel(a: Array, ref: Array) -> float:
    """Largest |a - ref| / |ref|, where ref = 0 counting as 0 if a = 0 too and as inf otherwise."""
    nz = ref != 0
    if np.any(a[~nz] != 0):
        return float("inf")
    return float(np.max(np.abs(a[nz] - ref[nz]) / np.abs(ref[nz]), initial=0.0))


if __name__ == "__main__":
    main()
