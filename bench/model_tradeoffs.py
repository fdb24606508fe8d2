"""Speed against accuracy of the model module's dials, each against its exact path in the same run.

1. Schlick against exact Fresnel (dielectric and conductors).
2. Smith-Schlick (k = alpha/2) against exact Smith G1 for GGX.
3. float32 against float64 evaluation of a GGX conductor Cook-Torrance BRDF.
4. Sample count of the directional albedo, quadrature and Monte Carlo, against a converged reference.

Run: ``.venv/bin/python -m bench.model_tradeoffs [--out DIR]``; prints tables and writes one PNG figure.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import itertools
import math
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt

from bench._common import (
    DEFAULT_OUT,
    best_time,
    format_table,
    load_average,
    machine_description,
    save_figure,
    uniform_hemisphere,
)
from model import fresnel, microfacet
from model.base import Model
from model.cook_torrance import CookTorrance
from model.integrate import directional_albedo

Array = npt.NDArray[np.floating]
Data = dict[str, Any]

N_TIMED = 1_000_000
# Best of many: the machine is shared, and noise only ever adds time (see bench._common.best_time).
REPEATS = 15
CHANNELS = ("R", "G", "B")

# Complex indices n + i k at 650, 550 and 450 nm (R, G, B), interpolated from the tables Mitsuba 3
# ships in mitsuba/data/ior/*.spd (luxpop.com database, itself compiled from Palik, "Handbook of
# Optical Constants of Solids"). Per channel because Schlick's error depends strongly on n and k,
# and a single 550 nm value would hide the worst channel (e.g. gold's blue, copper's red).
METALS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "aluminium": ((1.475, 0.959, 0.618), (7.794, 6.687, 5.469)),
    "gold": ((0.168, 0.350, 1.508), (3.138, 2.714, 1.879)),
    "chromium": ((3.638, 3.116, 1.928), (4.364, 4.423, 4.168)),
    "silver": ((0.139, 0.125, 0.152), (4.129, 3.340, 2.470)),
    "copper": ((0.217, 0.958, 1.166), (3.638, 2.577, 2.394)),
}
GLASS_ETA = 1.5
# Published anchors: Schlick's maximum absolute error, and the GGX white-furnace albedo at
# normal incidence with F = 1.
REF_FRESNEL = {"glass": 0.04, "aluminium": 0.09, "chromium": 0.19}
REF_FURNACE = {0.1: 0.99, 0.5: 0.69, 1.0: 0.31}


def _deg(cos: Array) -> Array:
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _ms(seconds: float) -> str:
    return f"{1e3 * seconds:.1f}"


def fresnel_dial(rng: np.random.Generator) -> Data:
    """Schlick against exact Fresnel: error over a dense cos grid, time per 1e6 evaluations."""
    c = np.linspace(0.0, 1.0, 200_001)
    # (material, channel label, f0, exact reflectance over the grid)
    cases: list[tuple[str, str, float, Array]] = [
        ("glass", "-", float(fresnel.f0_from_ior(GLASS_ETA)), fresnel.dielectric(c, GLASS_ETA))
    ]
    for name, (etas, ks) in METALS.items():
        for ch, eta, k in zip(CHANNELS, etas, ks, strict=True):
            cases.append((name, ch, float(fresnel.f0_from_ior(eta, k)), fresnel.conductor(c, eta, k)))
    rows, curves = [], {}
    for name in ["glass", *METALS]:
        per = [(ch, f0, np.abs(fresnel.schlick(c, f0) - ex)) for m, ch, f0, ex in cases if m == name]
        ch, _, err = max(per, key=lambda t: float(t[2].max()))
        i = int(np.argmax(err))
        f0s = "/".join(f"{f0:.3f}" for _, f0, _ in per)
        g_max = next(float(e.max()) for cc, _, e in per if cc in ("G", "-"))
        ref = REF_FRESNEL.get(name)
        rows.append([name, f0s, ch, f"{err[i]:.4f}", f"{_deg(c[i]):.1f}",
                     f"{np.mean([e.mean() for _, _, e in per]):.4f}", f"{g_max:.4f}",
                     "-" if ref is None else f"{ref:.2f}"])
        curves[name] = (_deg(c), err, ch)
    x = rng.random(N_TIMED)
    eta, k = METALS["gold"][0][1], METALS["gold"][1][1]
    t_schlick = best_time(lambda: fresnel.schlick(x, 0.04), REPEATS)
    t_diel = best_time(lambda: fresnel.dielectric(x, GLASS_ETA), REPEATS)
    t_cond = best_time(lambda: fresnel.conductor(x, eta, k), REPEATS)
    print("\n## 1. Schlick against exact Fresnel (errors over 200001 cos_i values uniform in [0, 1])")
    print(format_table(
        ["material", "F0 (R/G/B)", "worst ch", "max |err|", "at theta_i (deg)", "mean |err| (all ch)",
         "max |err| G", "REFERENCE"], rows))
    print(f"\nTime per 1e6 evaluations (float64, best of {REPEATS}); anchor: exact Fresnel")
    print(format_table(["function", "ms / 1e6", "exact / schlick"], [
        ["schlick", _ms(t_schlick), "1.00"],
        ["dielectric (exact, anchor)", _ms(t_diel), f"{t_diel / t_schlick:.2f}"],
        ["conductor (exact, anchor)", _ms(t_cond), f"{t_cond / t_schlick:.2f}"],
    ]))
    return {"curves": curves, "t": (t_schlick, t_diel, t_cond)}


def masking_dial(rng: np.random.Generator) -> Data:
    """Smith-Schlick (k = alpha/2) against exact GGX Smith G1 over cos in (0, 1]."""
    c = np.linspace(0.0, 1.0, 200_001)[1:]
    alphas = [0.01, 0.05, 0.1, 0.3, 0.5, 1.0]
    rows, max_err, mean_err = [], [], []
    for a in alphas:
        err = np.abs(microfacet.smith_schlick_g1(c, a / 2) - microfacet.smith_g1(c, a))
        i = int(np.argmax(err))
        max_err.append(float(err[i]))
        mean_err.append(float(err.mean()))
        at = f"{_deg(c[i]):.2f}" if err[i] > 1e-12 else "-"  # a roundoff maximum has no meaningful angle
        rows.append([f"{a:g}", f"{err[i]:.2e}", at, f"{err.mean():.2e}"])
    x = rng.random(N_TIMED)
    t_exact = best_time(lambda: microfacet.smith_g1(x, 0.1), REPEATS)
    t_schlick = best_time(lambda: microfacet.smith_schlick_g1(x, 0.05), REPEATS)
    print("\n## 2. Smith-Schlick (k = alpha/2) against exact Smith G1, GGX (200000 cos values in (0, 1])")
    print(format_table(["alpha", "max |err|", "at theta (deg)", "mean |err|"], rows))
    print("REFERENCE: up to 0.14 at alpha 0.1, exact at alpha 1")
    print(f"\nTime per 1e6 evaluations (float64, best of {REPEATS}); anchor: exact Smith G1")
    print(format_table(["function", "ms / 1e6", "exact / schlick"], [
        ["smith_schlick_g1", _ms(t_schlick), "1.00"],
        ["smith_g1 (exact, anchor)", _ms(t_exact), f"{t_exact / t_schlick:.2f}"],
    ]))
    return {"alphas": alphas, "max": max_err, "mean": mean_err, "t": (t_schlick, t_exact)}


def _kernel_in_use() -> bool:
    # The numba kernel is optional (added in parallel): measure it only once CookTorrance.eval
    # dispatches away from the numpy path; the module existing alone proves nothing.
    try:
        present = importlib.util.find_spec("model.kernels") is not None
    except ImportError:
        present = False
    return present and CookTorrance.eval is not Model.eval


FLOOR = 1e-6  # 1/sr: relative error is not meaningful for values this close to zero


def precision_dial(rng: np.random.Generator) -> Data:
    """float32 against float64 on the same 1e6 random pairs of a GGX gold conductor."""
    wi32, wo32 = (uniform_hemisphere(rng, N_TIMED, np.float32) for _ in range(2))
    # Both precisions evaluate the very same (float32-representable) directions, so the difference
    # is the arithmetic's alone, not the rounding of the inputs.
    wi64, wo64 = wi32.astype(np.float64), wo32.astype(np.float64)
    kernel = _kernel_in_use()
    rows, rel_errs = [], {}
    repeats = 5
    for a in (0.01, 0.1, 0.5):
        m = CookTorrance(alpha=a, eta=METALS["gold"][0], k=METALS["gold"][1])
        f64 = Model.eval(m, wi64, wo64)
        f32 = Model.eval(m, wi32, wo32)
        keep = f64 > FLOOR
        rel = np.abs(f32[keep].astype(np.float64) - f64[keep]) / f64[keep]
        rel_errs[a] = rel
        t64 = best_time(partial(Model.eval, m, wi64, wo64), repeats)
        t32 = best_time(partial(Model.eval, m, wi32, wo32), repeats)
        row = [f"{a:g}", _ms(t64), _ms(t32), f"{t64 / t32:.2f}", f"{rel.max():.2e}", f"{rel.mean():.2e}",
               f"{np.quantile(rel, 0.999):.2e}", f"{100 * (1 - keep.mean()):.3f}"]
        if kernel:
            k64 = best_time(partial(m.eval, wi64, wo64), REPEATS)
            k32 = best_time(partial(m.eval, wi32, wo32), REPEATS)
            kerr64 = np.abs(m.eval(wi64, wo64)[keep] - f64[keep]) / f64[keep]
            kerr32 = np.abs(m.eval(wi32, wo32)[keep].astype(np.float64) - f64[keep]) / f64[keep]
            row += [_ms(k64), _ms(k32), f"{t64 / k64:.1f}", f"{kerr64.max():.1e}", f"{kerr32.max():.1e}"]
        rows.append(row)
    print("\n## 3. float32 against float64: CookTorrance GGX, exact Smith, gold conductor (RGB), "
          "1e6 random pairs uniform on the hemisphere")
    print(f"numpy path Model.eval, best of {repeats} (kernel: CookTorrance.eval, best of {REPEATS}); anchor: "
          f"numpy float64. Relative errors over the values with f64 > {FLOOR:g} 1/sr (excluded %: excl)")
    headers = ["alpha", "f64 ms", "f32 ms", "f64/f32", "max rel", "mean rel", "p99.9 rel", "excl"]
    if kernel:
        headers += ["kernel f64 ms", "kernel f32 ms", "numpy/kernel f64", "kernel f64 max rel",
                    "kernel f32 max rel"]
    print(format_table(headers, rows))
    if not kernel:
        print("CookTorrance.eval does not use a numba kernel (yet): it is the numpy path measured above")
    return {"rel": rel_errs}


ALB_ALPHAS = (0.05, 0.2, 0.5)
ALB_THETAS = (0.0, 60.0, 85.0)
ALB_NS = (256, 1024, 4096, 16384, 65536)
TARGET = 1e-3


def _furnace(alpha: float) -> CookTorrance:
    # F = 1 everywhere (Schlick with f0 = 1), so the albedo measures D and G alone.
    return CookTorrance(alpha=alpha, fresnel="schlick", f0=1.0)


def _wi(theta_deg: float) -> Array:
    t = math.radians(theta_deg)
    return np.array([math.sin(t), 0.0, math.cos(t)])


def reference_albedo(model: CookTorrance, theta_i_deg: float, n: int = 256) -> float:
    """Directional albedo of a GGX model to ~1e-12, by Gauss-Legendre quadrature over the half vector.

    Neither candidate reference the brief suggests is good enough (the printed table shows it): the
    (cos theta, phi) grid of 2^20 points puts ~2 points across the 0.5 degree wide azimuthal extent of
    the alpha = 0.05 lobe at 85 degrees, and MC with 4M samples has a standard error of ~4e-4. Here
    the integral runs over the half vector h instead (d wo = 4 (wi.h) dh), with theta_h mapped through
    the GGX CDF u = tan^2/(alpha^2 + tan^2) so the peak of D is spread evenly, and phi_h limited to the
    arc where wo is above the horizon: |phi_h| < arccos(-cot(2 theta_h) cot(theta_i)), full for
    theta_h < 45 - theta_i/2 and empty beyond 45 + theta_i/2. Those two breakpoints split theta_h into
    pieces; a smoothstep map in each piece hides the square-root behaviour at its ends, and the
    integrand is then analytic, so n x n points per piece converge geometrically.
    """
    a, ti = float(model.alpha), math.radians(theta_i_deg)
    wi = _wi(theta_i_deg)

    def u_of(theta_h: float) -> float:
        t2 = math.tan(theta_h) ** 2
        return t2 / (a * a + t2)

    x, w = np.polynomial.legendre.leggauss(n)
    s = 0.5 * (x + 1.0)
    total = 0.0
    breaks = (0.0, u_of(math.pi / 4 - ti / 2), u_of(math.pi / 4 + ti / 2))
    for lo, hi in itertools.pairwise(breaks):
        if hi <= lo:
            continue
        u = lo + (hi - lo) * s * s * (3.0 - 2.0 * s)
        wu = (hi - lo) * 0.5 * w * 6.0 * s * (1.0 - s)
        th = np.arctan(a * np.sqrt(u / (1.0 - u)))
        sh, ch = np.sin(th), np.cos(th)
        if ti > 0:
            arc = np.arccos(np.clip(-math.cos(ti) * np.cos(2 * th) / (math.sin(ti) * np.sin(2 * th)), -1, 1))
        else:
            arc = np.where(th < math.pi / 4, math.pi, 0.0)
        # The model is isotropic and wi lies in the xz plane: integrate phi over [0, arc] and double.
        phi = arc[:, None] * s[None, :]
        wphi = arc[:, None] * 0.5 * w[None, :]
        h = np.stack([sh[:, None] * np.cos(phi), sh[:, None] * np.sin(phi), np.broadcast_to(ch[:, None],
                     phi.shape)], axis=-1)
        d = np.sum(h * wi, axis=-1)  # not h @ wi: a BLAS call whose threads spin against other load
        wo = 2.0 * d[..., None] * h - wi
        f = model.eval(wi, wo.reshape(-1, 3)).reshape(phi.shape)
        # d u = 2 pi D cos sin d theta_h, so d wo = 4 (wi.h) sin d theta_h d phi = 4 (wi.h) du dphi / (2 pi D cos).
        jac = 4.0 * d / (2.0 * math.pi * microfacet.ggx_d(ch, a)[:, None] * ch[:, None])
        total += 2.0 * float(np.sum(f * np.maximum(wo[..., 2], 0.0) * jac * wphi * wu[:, None]))
    return total


def albedo_dial() -> Data:
    """Albedo error and time against the sample count, for quadrature and Monte Carlo."""
    cases = [(a, t) for a in ALB_ALPHAS for t in ALB_THETAS]
    ref = {c: reference_albedo(_furnace(c[0]), c[1]) for c in cases}
    t_ref = best_time(lambda: reference_albedo(_furnace(0.2), 60.0), 3)
    # Why this reference and not the two candidates: measure all three against each other.
    rows = []
    for a, t in cases:
        m, w = _furnace(a), _wi(t)
        coarse = reference_albedo(m, t, 128)
        quad = float(directional_albedo(m, w, 2**20).value)
        # 4M MC samples in four independent 1M batches (same estimator, a quarter of the memory).
        mcs = [directional_albedo(m, w, 2**20, method="mc", rng=seed) for seed in range(1, 5)]
        mc = float(np.mean([e.value for e in mcs]))
        se = float(np.sqrt(np.sum([e.stderr**2 for e in mcs]))) / 4
        r = ref[(a, t)]
        rows.append([f"{a:g}", f"{t:g}", f"{r:.9f}", f"{abs(r - coarse):.0e}", f"{quad - r:+.1e}",
                     f"{mc - r:+.1e}", f"{se:.0e}"])
    path = "the numba kernel" if _kernel_in_use() else "the numpy path"
    print(f"\n## 4. Directional albedo, F = 1 (Schlick f0 = 1), GGX, exact Smith; CookTorrance.eval is {path}")
    print(f"Reference: half-vector Gauss-Legendre, 2 x 256 x 256 evaluations, {_ms(t_ref)} ms per call. "
          "Candidates against it:")
    print(format_table(["alpha", "theta_i", "reference", "|ref - ref(128^2)|", "quadrature 2^20 - ref",
                        "mc 4M - ref", "mc 4M stderr"], rows))
    err: dict[str, Array] = {}
    times: dict[str, Array] = {}
    for method in ("quadrature", "mc"):
        e = np.zeros((len(cases), len(ALB_NS)))
        tt = np.zeros_like(e)
        need = []
        for i, (a, t) in enumerate(cases):
            m, w = _furnace(a), _wi(t)
            for j, n in enumerate(ALB_NS):
                est = directional_albedo(m, w, n, method=method, rng=0)
                e[i, j] = abs(float(est.value) - ref[(a, t)])
                tt[i, j] = best_time(partial(directional_albedo, m, w, n, method=method), max(5, 2**17 // n))
            if method == "mc":
                # One seed's error is luck; the standard error decides how many samples 1e-3 takes.
                need.append(f"{ALB_NS[-1] * (float(est.stderr) / TARGET) ** 2:.1e}")
            else:
                ok = [j for j in range(len(ALB_NS)) if np.all(e[i, j:] <= TARGET)]
                need.append(str(ALB_NS[ok[0]]) if ok else f">{ALB_NS[-1]}")
        err[method], times[method] = e, np.median(tt, axis=0)
        _print_albedo_table(method, cases, e, need, times[method], t_ref)
    print("n for 1e-3: quadrature, the smallest n from which on |error| <= 1e-3; mc, the n at which the "
          "standard error is 1e-3 (65536 (stderr_65536 / 1e-3)^2)")
    rows = []
    for a, anchor in REF_FURNACE.items():
        v = reference_albedo(_furnace(a), 0.0)
        exact = f"{1 - math.log(2):.9f}" if a == 1.0 else "-"
        rows.append([f"{a:g}", f"{v:.9f}", f"{anchor:.2f}", exact])
    print("\nWhite furnace (F = 1, GGX, exact Smith), theta_i = 0, half-vector reference")
    print(format_table(["alpha", "albedo", "REFERENCE", "closed form 1 - ln 2"], rows))
    return {"err": err, "times": times}


def _print_albedo_table(
    method: str, cases: Sequence[tuple[float, float]], e: Array, need: list[str], times: Array, t_ref: float
) -> None:
    rows = [[f"{a:g}", f"{t:g}", *(f"{x:.1e}" for x in e[i]), need[i]] for i, (a, t) in enumerate(cases)]
    rows.append(["time", "ms", *(f"{1e3 * x:.2f}" for x in times), ""])
    rows.append(["time /", "ref", *(f"{x / t_ref:.2f}" for x in times), ""])
    print(f"\n|error| of method '{method}' against the reference "
          "(time: best of max(5, 131072 / n) calls, median over the 9 cases)")
    print(format_table(["alpha", "theta_i", *(f"n={n}" for n in ALB_NS), "n for 1e-3"], rows))


def plot(path: Path, fres: Data, mask: Data, prec: Data, alb: Data) -> None:
    """2x2 figure, one panel per dial."""
    fig, ax = plt.subplots(2, 2, figsize=(12, 9))
    p = ax[0, 0]
    for name, (theta, e, ch) in fres["curves"].items():
        p.plot(theta, e, label=f"{name} ({ch})" if ch != "-" else name)
    t_s, t_d, t_c = fres["t"]
    p.set(xlabel="incidence angle theta_i (deg)", ylabel="|Schlick - exact| (reflectance)", xlim=(0, 90),
          title=f"Fresnel: Schlick {t_d / t_s:.1f}x (dielectric), {t_c / t_s:.1f}x (conductor) faster")
    p.legend(fontsize=8)
    p = ax[0, 1]
    p.plot(mask["alphas"], mask["max"], "o-", label="max over cos")
    p.plot(mask["alphas"], mask["mean"], "s--", label="mean over cos")
    t_s, t_e = mask["t"]
    p.set(xscale="log", xlabel="GGX alpha", ylabel="|Smith-Schlick G1 - exact G1| (over cos in (0, 1])",
          title=f"Masking: Smith-Schlick {t_e / t_s:.1f}x faster than exact G1")
    p.legend(fontsize=8)
    p = ax[1, 0]
    bins = np.logspace(-10, -2, 81)
    for a, rel in prec["rel"].items():
        p.hist(np.maximum(rel, 1e-10), bins=bins, histtype="step", label=f"alpha {a:g}")
    p.set(xscale="log", yscale="log", xlabel="relative error of float32 against float64 (exact matches at 1e-10)",
          ylabel="pairs per bin", title="float32: Cook-Torrance GGX gold, 1e6 random pairs")
    p.legend(fontsize=8)
    p = ax[1, 1]
    for method, style in (("quadrature", "-"), ("mc", "--")):
        t = 1e3 * alb["times"][method]
        e = np.maximum(alb["err"][method], 1e-16)
        p.plot(t, e.max(axis=0), "o" + style, label=f"{method}: max over 9 cases")
        p.plot(t, np.median(e, axis=0), "s" + style, label=f"{method}: median over 9 cases")
        for x, y, n in zip(t, e.max(axis=0), ALB_NS, strict=True):
            p.annotate(str(n), (x, y), fontsize=7, textcoords="offset points", xytext=(3, 3))
    p.axhline(TARGET, color="grey", lw=0.8, label="1e-3")
    p.set(xscale="log", yscale="log", xlabel="time per albedo (ms)", ylabel="|albedo - reference|",
          title="Albedo: n = 256 .. 65536 evaluations")
    p.legend(fontsize=8)
    save_figure(fig, path)


def main(argv: Sequence[str] | None = None) -> None:
    """Run the four dials, print their tables and write the figure."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="directory for the figure")
    args = ap.parse_args(argv)
    print(f"# model_tradeoffs, {datetime.date.today().isoformat()}")
    print(f"Machine: {machine_description()}; before: {load_average()} (the machine may be shared)")
    rng = np.random.default_rng(0)
    fres = fresnel_dial(rng)
    mask = masking_dial(rng)
    prec = precision_dial(rng)
    alb = albedo_dial()
    path = args.out / "model_tradeoffs.png"
    plot(path, fres, mask, prec, alb)
    print(f"\nFigure: {path}\nafter: {load_average()}")


if __name__ == "__main__":
    main()
