"""``gonio adaptive``: a sweep that chooses its own points, round by round, where the fit is least certain."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gonio.cli_run import EXIT_OK, _rig, _sigterm_as_interrupt, _stopped


def _adaptive(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from analysis.ladder import parse_models
    from rig.run.adaptive import AdaptiveSettings, Round, run_adaptive
    from rig.run.runner import RunStopped

    spec = None if args.model == "auto" else parse_models(args.model)[0]
    settings = AdaptiveSettings(budget=args.budget, initial=args.initial, batch=args.batch,
                                max_theta_deg=args.max_theta, target_snr=args.snr,
                                reference_snr=args.reference_snr, seed=args.seed)  # fmt: skip
    rig = _rig(args.rig)
    print(f"adaptive sweep into {args.out}: {settings.budget} captures, model {args.model}", file=sys.stderr)
    # A bar over the captures (rounds differ in size), its ETA from the rounds done; round lines print above it.
    bar = tqdm(total=settings.budget, desc="adaptive", unit="capture", disable=args.quiet, dynamic_ncols=True)

    def on_round(rnd: Round) -> None:
        bar.update(rnd.captures - bar.n)
        bar.set_postfix_str(f"round {rnd.index}", refresh=True)

    def say(line: str) -> None:
        tqdm.write(line, file=sys.stderr)

    try:
        with _sigterm_as_interrupt(), bar:
            result = run_adaptive(rig, Path(args.out), spec, settings, on_round=on_round, log=say)
    except RunStopped as exc:
        return _stopped(exc)
    last = result.rounds[-1]
    print(f"{last.captures} captures in {len(result.rounds)} rounds, {result.rig_time_s / 60:.1f} min rig time; "
          f"table {result.table}")  # fmt: skip
    print(last.fit.summary())
    return EXIT_OK


def add_adaptive_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio adaptive``."""
    p = sub.add_parser(
        "adaptive", help="measure where the current fit is least certain, round by round",
        description="An adaptive sweep: a space-filling first round, then rounds chosen from reachable "
        "candidates to lower the fitted BRDF's expected error the most (first order, from the fit's "
        "Jacobian). Each round is an ordinary run in OUT/round-NN; OUT/samples.csv holds every round's rows "
        "and OUT/adaptive.json the fits. Analyse it with `gonio analyze` on any round or fit OUT/samples.csv.",
        epilog="Example: gonio adaptive --rig examples/rig_simulated.toml --out runs/gold-adaptive "
        "--model ggx_conductor --budget 100",
    )  # fmt: skip
    p.add_argument("--rig", help="rig file (TOML); default: the built-in simulated rig")
    p.add_argument("--out", required=True, help="directory to create (must not exist or be empty)")
    p.add_argument("--model", default="auto", help="model fitted between rounds (a name gonio analyze --models "
                   "accepts), or auto: the model selection's choice each round (default)")  # fmt: skip
    p.add_argument("--budget", type=int, default=100, help="captures in all (default 100)")
    p.add_argument("--initial", type=int, default=20, help="captures of the first round (default 20)")
    p.add_argument("--batch", type=int, default=10, help="captures per later round (default 10)")
    p.add_argument("--snr", type=float, default=100.0, help="SNR goal of each capture (default 100)")
    p.add_argument("--reference-snr", type=float, default=None,
                   help="SNR goal of the reference readings (default: the rig's [reference] target_snr); each "
                   "round is its own run with about two, so a matte sample, whose fit is all calibration, "
                   "wants them about 2.5x the SNR a single long run would use")  # fmt: skip
    p.add_argument("--max-theta", type=float, default=70.0, help="largest zenith of any capture, deg (default 70)")
    p.add_argument("--seed", type=int, default=0, help="seed of the candidate pool (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_adaptive)
