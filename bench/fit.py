"""Time to fit a model to 10,000 BRDF samples, against the 1 s goal and against one model evaluation.

Samples: random direction pairs uniform over the hemisphere, the true model's values plus Gaussian noise
with known std errors (2 % relative plus a floor of 0.002 /sr), RGB. Fits: Lambert + GGX dielectric
(5 parameters), anisotropic Ward (6, the issue's size) and a GGX conductor (7), loss l2, with 1 start and
with the default 4 (screened on 2,000 samples, then polished on all). The anchor is one evaluation of the
true model at all samples (Model.eval, the kernel where it applies), so the ratio reads "a fit costs as
much as this many evaluations". The accuracy column is the largest |fitted - true| / reported std error.

Run: ``.venv/bin/python -m bench.fit [--samples N] [--repeats R] [--no-write]``.
"""

from __future__ import annotations

import argparse
import datetime
from functools import partial
from pathlib import Path

import numpy as np

from bench._common import (
    best_time,
    format_table,
    machine_description,
    markdown_table,
    uniform_hemisphere,
    write_section,
)
from model import CookTorrance, Ward
from model.base import Model
from model.fit import FitResult, FitSpec, Samples, fit, ggx_conductor, lambert_ggx, ward_anisotropic

DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
GOAL_S = 1.0
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


def max_z(res: FitResult, spec: FitSpec, model: Model) -> float:
    """Largest |fitted - true| in units of the reported std errors."""
    true = np.concatenate([np.broadcast_to(np.atleast_1d(getattr(model, p.name)), (3 if p.per_channel else 1,))
                           for p in spec.params])  # fmt: skip
    return float(np.max(np.abs(res.values - true) / res.std_errors))


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and print (and by default record) its figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--samples", type=int, default=10_000, help="samples per fit (default 10000)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repetitions, fastest kept (default 5)")
    parser.add_argument("--no-write", action="store_true", help="do not update docs/benchmarks.md")
    args = parser.parse_args(argv)
    machine = machine_description()
    print(machine)
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
    if args.no_write:
        return
    body = "\n".join([
        f"Measured {datetime.date.today()} on {machine}; `.venv/bin/python -m bench.fit --samples {args.samples}`.",
        "", f"Fitting {args.samples} noisy RGB samples (loss l2, fastest of {args.repeats}); the goal is a "
        "6-parameter fit of 10,000 samples in under 1 s; the anchor is one evaluation of the model at all samples:",
        "", markdown_table(head, rows),
    ])  # fmt: skip
    write_section(DOCS, "fit", body)


if __name__ == "__main__":
    main()
