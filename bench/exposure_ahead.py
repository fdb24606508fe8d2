"""Exposure planned ahead: a sharp lobe measured after a coarse first pass, planned from that pass or its fit.

A sharp gold lobe (Cook-Torrance GGX, alpha 0.04) on the simulated rig, lit at 20 deg, viewed in the plane:

1. a coarse first pass, stop-and-go, every 6 deg of theta_o (SNR 100), then ``gonio analyze``'s fit of it
   (``analysis.analyze.load_and_fit``: the model ladder, the chosen model written as fit.json writes it);
2. the fine sweep, every 4 deg (SNR 1000, so frames are as long as saturation allows: where the planned exposure
   is bound by the SNR goal, a brighter next point does not clip), measured in both motions (a continuous scan at
   5 deg/s, and stop-and-go), each three ways: planned from the previous point alone (the anchor), with
   ``[capture] exposure_model`` = the fit, and with ``exposure_from`` = the first pass's run directory.

For each: rig time (the simulated clock: moves, exposures, the points a clipped frame sends back to rest), scan
frames that clipped, points metered afresh (their first bracket clipped or came out dark) and topped up (it fell
short of the SNR goal), frames shot (light and metering test frames), predictions off by more than x4 (events), and
the readings against the anchor's: the largest |z| of the difference over both errors (planning ahead changes
exposures, not what is read).

    .venv/bin/python -m bench.exposure_ahead [--no-docs] [--seed N]
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from analysis.analyze import fit_json, load_and_fit
from bench._common import bench_parser, format_table, load_average, machine_description, markdown_table, record
from rig.run.config.files import RigConfig, SweepConfig, parse, rig_config, sweep_config
from rig.run.config.schema import RigFile, SweepFile
from rig.run.session import start_run
from rig.run.storage.store import RunStore

SHARP = {"model": "CookTorrance", "alpha": 0.04, "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}
THETA_I = 20.0
COARSE = [float(t) for t in range(-10, 52, 6)]
FINE = [float(t) for t in range(-10, 52, 4)]
SCAN = {"motion": "continuous", "scan_speed_deg_s": 5.0}
HEAD = ["motion", "planned from", "rig time (s)", "x anchor", "clipped frames", "metered afresh", "topped up",
        "frames", "off > x4", "largest z vs anchor"]  # fmt: skip


def _rig(seed: int) -> RigConfig:
    doc = {"simulation": {"material": SHARP, "seed": seed}, "reference": {"every": 25}}
    return rig_config(parse(doc, RigFile, "bench-rig.toml"), "bench-rig.toml")


def _sweep(theta_o: list[float], **capture: Any) -> SweepConfig:
    doc = {"sweep": {"kind": "in_plane", "theta_i_deg": [THETA_I], "theta_o_deg": theta_o}, "capture": capture}
    return sweep_config(parse(doc, SweepFile, "bench-sweep.toml"), "bench-sweep.toml")


def _outcome(run: Path, rig_time_s: float) -> dict[str, Any]:
    records = RunStore.read(run).records()
    points = sorted((r for r in records if r["kind"] == "point"), key=lambda r: r["index"])
    events = [r["event"] for r in records if r["kind"] == "event"]
    return {
        "rig_time_s": rig_time_s, "clipped": events.count("scan_clipped"),
        "off": events.count("exposure_prediction_off"),
        "metered": sum(any("metered afresh" in n for n in p["notes"]) for p in points),
        "topped": sum(any("topped up" in n for n in p["notes"]) for p in points),
        "frames": sum(len(p["exposures_s"]) + len(p["test_exposures_s"]) for p in points),
        "reading": np.array([p["reading"] for p in points]), "se": np.array([p["reading_std_error"] for p in points]),
    }  # fmt: skip


def measure(seed: int, tmp: Path) -> list[list[str]]:
    """The first pass, its fit, then the fine sweep six ways; the table's rows."""
    rig = _rig(seed)
    start_run(rig, _sweep(COARSE, target_snr=100.0), tmp / "coarse", progress=False)
    fit = fit_json(load_and_fit(tmp / "coarse", log=lambda *a, **k: None))
    (tmp / "fit.json").write_text(json.dumps(fit, indent=2))
    print(f"first pass: {len(COARSE)} points; fitted {fit['chosen']}: {json.dumps(fit['model'])}", flush=True)
    rows = []
    for motion, extra in (("continuous", SCAN), ("stop", {})):
        anchor: dict[str, Any] | None = None
        for source, key in (("previous (anchor)", {}), ("model (the fit)", {"exposure_model": str(tmp / "fit.json")}),
                            ("pass (first pass)", {"exposure_from": str(tmp / "coarse")})):  # fmt: skip
            name = f"{motion}-{source.split()[0]}"
            summary = start_run(rig, _sweep(FINE, target_snr=1000.0, **extra, **key), tmp / name, progress=False)
            got = _outcome(tmp / name, summary.rig_time_s)
            anchor = anchor or got
            z = np.abs(got["reading"] - anchor["reading"]) / np.hypot(got["se"], anchor["se"])
            rows.append([motion, source, f"{got['rig_time_s']:.1f}", f"{got['rig_time_s'] / anchor['rig_time_s']:.2f}",
                         str(got["clipped"]), str(got["metered"]), str(got["topped"]), str(got["frames"]),
                         str(got["off"]), "-" if got is anchor else f"{float(np.max(z)):.2f}"])  # fmt: skip
            print(format_table(HEAD, rows[-1:]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    """Measure, print the table, write the docs section."""
    parser = bench_parser(__doc__)
    parser.add_argument("--seed", type=int, default=3, help="simulator seed (default 3)")
    args = parser.parse_args(argv)
    machine, load = machine_description(), load_average()
    print(f"{machine}\n{load} before the run", flush=True)
    wall = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gonio-exposure-ahead-") as tmp:
        rows = measure(args.seed, Path(tmp))
    elapsed = time.perf_counter() - wall
    print("\n" + format_table(HEAD, rows) + f"\nwall time {elapsed:.0f} s")
    if args.no_docs:
        return 0
    record(
        "exposure_ahead", "Exposure planned ahead from a model or a first pass",
        f" --seed {args.seed}" if args.seed != 3 else "",
        f"{machine}, shared with other work ({load} before the run; wall time {elapsed:.0f} s).",
        f"A sharp gold lobe (GGX alpha 0.04) on the simulated rig (seed {args.seed}), lit at {THETA_I:g} deg. First "
        f"pass: stop-and-go every {COARSE[1] - COARSE[0]:g} deg of theta_o at SNR 100, fitted by `gonio analyze`'s "
        f"ladder (its fit.json is the model). The fine sweep, every {FINE[1] - FINE[0]:g} deg at SNR 1000 (frames "
        "as long as saturation allows), in a continuous scan (5 deg/s) and stop-and-go, planned three ways: from the "
        "previous point alone (the anchor), from the fit (`exposure_model`), from the first pass "
        "(`exposure_from`). Clipped frames: scan frames that saturated (measured again at rest, after the arm "
        "finished its sweep); metered afresh: points whose first bracket clipped or was dark; frames: light and "
        "metering test frames; off > x4: `exposure_prediction_off` events; largest z: the largest difference from "
        "the anchor's reading at the same point over both errors (the readings' values do not depend on the plan).",
        markdown_table(HEAD, rows),
        "One noise realisation (one seed); rig time is the simulated clock's, so the ratios do not depend on the "
        "machine.",
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
