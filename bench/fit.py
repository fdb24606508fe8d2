"""Time to fit a model to 10,000 BRDF samples and to a full MERL table, against the goals (1 s, 30 s).

Samples: random direction pairs uniform over the hemisphere, the true model's values plus Gaussian noise
with known std errors (2 % relative plus a floor of 0.002 /sr), RGB. Fits: Lambert + GGX dielectric
(5 parameters), anisotropic Ward (6, the issue's size) and a GGX conductor (7), loss l2, with 1 start and
with the default 4 (screened on 2,000 samples, then polished on all). The anchor is one evaluation of the
true model at all samples (Model.eval, the kernel where it applies), so the ratio reads "a fit costs as
much as this many evaluations". The accuracy column is the largest |fitted - true| / reported std error.

Full MERL table: there is no MERL file on this machine, so the table is tabulated from a known material
with ``MerlTable.from_model`` and every bin with data above the horizon becomes a sample
(``Samples.from_merl(table, None)``: 1,096,216 RGB samples, 3.3 million residuals). The spec has the
issue's 6 parameters: a Lambertian albedo per channel under one GGX conductor lobe with a grey index
(eta and k shared by the channels) and alpha, ``ggx_conductor(rho_d=True).shared("eta", "k")``. It is fitted
(default 4 starts) to the table of its own model, noise-free, where the parameters must come back to the
optimiser's tolerance, and to the table of the same material with a Beckmann lobe, which it cannot match
(as with measured data): that fit needs more iterations.

Run: ``.venv/bin/python -m bench.fit [--samples N] [--repeats R] [--merl-repeats R] [--no-merl] [--no-write]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
from functools import partial

import numpy as np

from bench._common import (
    BENCHMARKS_MD,
    best_time,
    format_table,
    machine_description,
    markdown_table,
    timed_calls,
    uniform_hemisphere,
    write_section,
)
from model import CookTorrance, Ward
from model.base import Model
from model.fit.solve import FitResult, FitSpec, Samples, fit, ggx_conductor, lambert_ggx, ward_anisotropic
from model.merl import MerlTable

GOAL_S = 1.0
MERL_GOAL_S = 30.0
MERL_SPEC = ggx_conductor(rho_d=True).shared("eta", "k")
MERL_TRUTH = CookTorrance(alpha=0.3, fresnel="conductor", eta=1.0, k=6.0, rho_d=(0.05, 0.1, 0.2))
MERL_CASES: list[tuple[str, CookTorrance]] = [
    ("GGX: the spec's own model", MERL_TRUTH),
    ("Beckmann: a misfit", dataclasses.replace(MERL_TRUTH, distribution="beckmann")),
]
CASES: list[tuple[FitSpec, Model]] = [
    (lambert_ggx(), CookTorrance(alpha=0.15, fresnel="dielectric", eta=1.5, rho_d=(0.2, 0.3, 0.4))),
    (ward_anisotropic(), Ward(rho_d=(0.2, 0.3, 0.4), rho_s=0.3, alpha_x=0.1, alpha_y=0.25, variant="balanced")),
    (ggx_conductor(), CookTorrance(alpha=0.3, eta=(1.657, 0.880, 0.521), k=(9.224, 6.270, 4.837))),
]


def samples_of(model: Model, n: int, seed: int) -> Samples:
    """n noisy samples of the model with known std errors."""
    rng = np.random.default_rng(seed)
    wi, wo = uniform_hemisphere(rng, n), uniform_hemisphere(rng, n)
    f = np.asarray(model.eval(wi, wo), dtype=np.float64).reshape(n, -1)
    se = 0.02 * f + 0.002
    return Samples(wi, wo, f + rng.normal(size=f.shape) * se, se)


def truth_of(spec: FitSpec, model: Model) -> np.ndarray:
    """The true parameter vector of the model in the spec's order."""
    return np.concatenate([np.broadcast_to(np.atleast_1d(getattr(model, p.name)), (3 if p.per_channel else 1,))
                           for p in spec.params])  # fmt: skip


def max_z(res: FitResult, spec: FitSpec, model: Model) -> float:
    """Largest |fitted - true| in units of the reported std errors."""
    return float(np.max(np.abs(res.values - truth_of(spec, model)) / res.std_errors))


def merl_rows(repeats: int) -> tuple[list[str], list[list[str]], str]:
    """Fit MERL_SPEC to every bin of the tabulated MERL_CASES; the table's header, rows and a note."""
    head = ["table made from", "spec", "params", "samples", "fit (s)", "ratio to 30 s goal", "one eval (ms)",
            "ratio to one eval", "max rel param error", "chi2/dof"]  # fmt: skip
    rows = []
    note = ""
    for label, model in MERL_CASES:
        table = MerlTable.from_model(model)
        s = Samples.from_merl(table, None)
        note = (f"{s.n:,} of {table.values[0].size:,} bins hold data above the horizon; the tables are "
                "MerlTable.from_model of CookTorrance(alpha=0.3, fresnel='conductor', eta=1.0, k=6.0, "
                "rho_d=(0.05, 0.1, 0.2)), GGX and Beckmann, not measured files")  # fmt: skip
        anchor = best_time(partial(model.eval, s.wi, s.wo), repeats=max(repeats, 3))
        res = fit(MERL_SPEC, s, warn=False)  # also the warm-up: the kernel's compiled code is loaded here
        t = min(timed_calls(partial(fit, MERL_SPEC, s, warn=False), repeats, warmup=0))
        rel = np.abs(res.values - truth_of(MERL_SPEC, model)) / truth_of(MERL_SPEC, model)
        error = f"{rel.max():.1e}" if model.distribution == "ggx" else "n/a (misfit)"
        rows.append([label, MERL_SPEC.name, str(res.n_params), f"{s.n:,}", f"{t:.2f}", f"{t / MERL_GOAL_S:.2f}",
                     f"{anchor * 1e3:.1f}", f"{t / anchor:.0f}", error, f"{res.reduced_chi2:.3g}"])  # fmt: skip
    return head, rows, note


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and print (and by default record) its figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--samples", type=int, default=10_000, help="samples per fit (default 10000)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repetitions, fastest kept (default 5)")
    parser.add_argument("--merl-repeats", type=int, default=2, help="timed full-MERL fits, fastest kept (default 2)")
    parser.add_argument("--no-merl", action="store_true", help="skip the full-MERL fits")
    parser.add_argument("--no-write", action="store_true", help="do not update docs/benchmarks.md")
    args = parser.parse_args(argv)
    machine = machine_description()
    # The machine may be shared: the load when the run starts says how much of it this run had.
    load = f"load average {os.getloadavg()[0]:.1f} at the start"
    print(f"{machine}; {load}")
    head = ["model", "params", "starts", "fit (s)", "ratio to 1 s goal", "one eval (ms)", "ratio to one eval",
            "max abs z"]  # fmt: skip
    rows = []
    for spec, model in CASES:
        s = samples_of(model, args.samples, seed=0)
        anchor = best_time(partial(model.eval, s.wi, s.wo), repeats=args.repeats)
        for starts in (1, 4):
            res = fit(spec, s, starts=starts, warn=False)
            t = best_time(partial(fit, spec, s, starts=starts, warn=False), repeats=args.repeats)
            rows.append([spec.name, str(res.n_params), str(starts), f"{t:.3f}", f"{t / GOAL_S:.2f}",
                         f"{anchor * 1e3:.2f}", f"{t / anchor:.0f}", f"{max_z(res, spec, model):.2f}"])  # fmt: skip
    print(format_table(head, rows))
    merl: list[str] = []
    if not args.no_merl:
        m_head, m_rows, note = merl_rows(args.merl_repeats)
        print(f"\nFull MERL table ({note}):")
        print(format_table(m_head, m_rows))
        merl = [
            "", f"Fitting a full MERL table (fastest of {args.merl_repeats}, default 4 starts); the goal is a "
            f"6-parameter fit in under {MERL_GOAL_S:g} s on a 2-core machine. {note[0].upper()}{note[1:]} "
            "(no MERL file on this machine). Every such bin is a sample (phi_h = 0), std errors assumed 5 %. "
            "The spec is `ggx_conductor(rho_d=True).shared(\"eta\", \"k\")`: rho_d per channel, eta, k, alpha:",
            "", markdown_table(m_head, m_rows),
        ]  # fmt: skip
    if args.no_write:
        return
    body = "\n".join([
        f"Measured {datetime.date.today()} on {machine} ({load}); "
        f"`.venv/bin/python -m bench.fit --samples {args.samples}`.",
        "", f"Fitting {args.samples} noisy RGB samples (loss l2, fastest of {args.repeats}); the goal is a "
        "6-parameter fit of 10,000 samples in under 1 s; the anchor is one evaluation of the model at all samples:",
        "", markdown_table(head, rows), *merl,
    ])  # fmt: skip
    write_section(BENCHMARKS_MD, "fit", body)


if __name__ == "__main__":
    main()
