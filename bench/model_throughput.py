"""Evaluations per second of a GGX conductor, numpy in and numpy out: our numpy path, our kernel, Mitsuba.

CookTorrance with GGX, exact separable Smith masking and conductor Fresnel (aluminium, RGB eta and k,
alpha 0.3) on random direction pairs (N, 3) float64, output (N, 3); against Mitsuba 3's
``roughconductor`` with the same parameters in ``llvm_ad_rgb`` (the anchor: vectorised, JIT-compiled,
float32) and ``scalar_rgb`` (one Python call per pair, the only way to drive it from numpy).
The Mitsuba timings include the numpy -> drjit -> numpy conversions; one more row times Mitsuba's
evaluation alone (drjit arrays in and out) to show what those conversions cost. The kernel and
Mitsuba llvm are timed in alternating blocks (see :func:`block_medians`), so load from the rest of
the machine hits both, once on every core (numba's and drjit's default thread counts) and once on one
thread each. The physical anchor of each is a streaming copy of the same bytes: ``np.copyto`` of an
array the size of the float64 inputs plus outputs (in one thread per core, or one), and each path's
numpy bytes (inputs + outputs) per second as a fraction of that copy's bandwidth (read + write).

Run: ``.venv/bin/python -m bench.model_throughput [--pairs N] [--repeats R]``.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import statistics
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import Any

import drjit as dr
import mitsuba as mi
import numba
import numpy as np
import numpy.typing as npt

from bench._common import format_table, load_average, machine_description, median_time, uniform_hemisphere
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
COPY = "memory: np.copyto of inputs + outputs (anchor)"
ORDER = (NUMPY, KERNEL, KERNEL32, ANCHOR, EVAL_ONLY, COPY, SCALAR_LOOP)
#: Bytes per pair in numpy, inputs + outputs: float64 (N, 3) x 2 in and (N, 3) out; float32 half; Mitsuba
#: float64 in and float32 out. The copy anchor moves the float64 figure twice (read and write).
BYTES = {KERNEL: 72, KERNEL32: 36, ANCHOR: 60, EVAL_ONLY: 36, COPY: 72}


def _bsdf() -> Any:
    return mi.load_dict({
        "type": "roughconductor", "distribution": "ggx", "alpha": ALPHA, "sample_visible": False,
        "eta": {"type": "rgb", "value": list(ALUMINIUM_ETA)},
        "k": {"type": "rgb", "value": list(ALUMINIUM_K)},
    })


def mitsuba_llvm_eval(bsdf: Any, wi: Array, wo: Array) -> Array:
    """f_r cos(theta_o) in 1/sr of a Mitsuba BSDF in a jit variant, all pairs in one call, (N, 3) float32."""
    si = dr.zeros(mi.SurfaceInteraction3f)
    # Column by column: drjit casts to float32 itself, quicker than a transposed numpy copy.
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
    a call and slow the other library's next call (docs/benchmarks.md).
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


class StreamingCopy:
    """np.copyto of one float64 array the size of a path's inputs + outputs, split over ``threads`` threads."""

    def __init__(self, n_pairs: int, threads: int) -> None:
        self.src = np.ones(n_pairs * BYTES[COPY] // 8)
        self.dst = np.empty_like(self.src)
        self.threads = threads
        self.pool = ThreadPoolExecutor(threads) if threads > 1 else None

    def __call__(self) -> None:
        """Copy once (numpy releases the GIL in copyto, so the threads' slices run in parallel)."""
        if self.pool is None:
            np.copyto(self.dst, self.src)
            return
        bounds = np.linspace(0, self.src.size, self.threads + 1).astype(int)
        parts = [(self.dst[a:b], self.src[a:b]) for a, b in itertools.pairwise(bounds)]
        list(self.pool.map(lambda ds: np.copyto(*ds), parts))

    def close(self) -> None:
        """Stop the copy threads."""
        if self.pool is not None:
            self.pool.shutdown()


def measure(n: int, repeats: int) -> tuple[dict[tuple[str, int], tuple[int, float]], dict[str, str]]:
    """(pairs, median seconds) per (path, threads), and why each unavailable Mitsuba variant does not load."""
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
    cores = numba.get_num_threads()
    result: dict[tuple[str, int], tuple[int, float]] = {}
    for threads in dict.fromkeys((cores, 1)):
        copy = StreamingCopy(n, threads)
        numba.set_num_threads(threads)
        fns: dict[str, Callable[[], object]] = {**fast, COPY: copy}
        if LLVM in unavailable:
            seconds = block_medians(fns, ROUNDS, per_block)
        else:
            with use_variant(LLVM):
                dr.set_thread_count(threads)
                bsdf = _bsdf()
                si = dr.zeros(mi.SurfaceInteraction3f)
                si.wi, wo_dr = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2]), mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2])
                seconds = block_medians({
                    **fns, ANCHOR: partial(mitsuba_llvm_eval, bsdf, wi, wo),
                    EVAL_ONLY: partial(mitsuba_llvm_eval_only, bsdf, si, wo_dr),
                }, ROUNDS, per_block)
                if threads == cores:
                    f_mitsuba = mitsuba_llvm_eval(bsdf, wi, wo).astype(np.float64)
                    # Mitsuba's eval includes the cosine foreshortening of the outgoing direction.
                    accuracy.append(f"kernel * cos(theta_o) vs Mitsuba {LLVM} (float32): max relative "
                                    f"difference {_max_rel(f_mitsuba, ours * wo[:, 2:3]):.2e}")
                dr.set_thread_count(cores)
        copy.close()
        result.update({(name, threads): (n, s) for name, s in seconds.items()})
    numba.set_num_threads(cores)
    result[NUMPY, 1] = (n, median_time(partial(Model.eval, model, wi, wo), max(1, repeats // 3)))
    if SCALAR not in unavailable:
        m = min(n, N_SCALAR)
        with use_variant(SCALAR):
            result[SCALAR_LOOP, 1] = (
                m, median_time(partial(mitsuba_scalar_eval, _bsdf(), wi[:m], wo[:m]), 3))
    print("\n".join(accuracy))
    return result, unavailable


def table_rows(result: dict[tuple[str, int], tuple[int, float]]) -> list[list[str]]:
    """One row per (path, threads): time, rate, ratio to Mitsuba llvm and share of the copy's bandwidth."""
    rows = []
    for threads in sorted({t for _, t in result}, reverse=True):
        anchor = result.get((ANCHOR, threads))
        copy = result.get((COPY, threads))
        for name in ORDER:
            if (name, threads) not in result:
                continue
            pairs, s = result[name, threads]
            rate = pairs / s
            ratio = f"{rate / (anchor[0] / anchor[1]):.3g}" if anchor is not None and name != COPY else "-"
            if copy is not None and name in BYTES:
                # The copy moves its bytes twice (read and write); a path moves its numpy bytes once.
                bandwidth = 2 * BYTES[COPY] * copy[0] / copy[1]
                share = f"{BYTES[name] * rate / bandwidth:.2f}" if name != COPY else f"{bandwidth / 1e9:.3g} GB/s"
            else:
                share = "-"
            rows.append([name, str(threads), f"{pairs:,}", f"{s:.3g}", f"{rate / 1e6:.3g}", ratio, share])
    return rows


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
    print(f"before: {load_average()} (the machine may be shared)")
    result, unavailable = measure(args.pairs, args.repeats)
    print(f"after: {load_average()}")
    rows = table_rows(result)
    rows += [[f"Mitsuba {name}", "-", "-", "-", "unavailable", "-", "-"] for name in unavailable]
    print(format_table(
        ["path", "threads", "pairs", "median s", "M evals/s", "vs Mitsuba llvm", "of copy bandwidth"], rows))
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
