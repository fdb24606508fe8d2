"""The docs section of bench/continuous_scan: command, machine, table, and what a reader needs to weigh the figures."""

from __future__ import annotations

import argparse
import math
from typing import Any, Protocol

from analysis.batch.tradeoff import MAX_THETA, REFERENCE_SNR, SNR
from bench._common import record
from bench._modes import ERROR_GOAL, POINT_RESOLUTION, THROUGHPUT_GOAL


class Row(Protocol):
    """What the verdicts read of a bench row (``bench.continuous_scan.Outcome``)."""

    mode: str
    sweep: str
    dial: str
    rig_time_s: float
    scores: dict[str, Any]

    @property
    def per_hour(self) -> float:
        """Samples per hour of rig time."""
        ...


#: The rows measured at rest: a scanned row is compared with the one of its sweep and reading mode.
AT_REST = ("stop-and-go", "image")


def _x(a: float, b: float) -> str:
    return f"{a / b:.2f}x" if math.isfinite(a) and math.isfinite(b) and b else "-"


def verdicts(label: str, outcomes: list[Row]) -> list[str]:
    """One line per scanned row: against the anchor (the goals) and against the same sweep at rest."""
    anchor = outcomes[0]
    lines = []
    for o in outcomes[1:]:
        if o.mode == "stop-and-go":
            continue
        # The same sweep at rest: the stop-and-go row whose label this row's extends the most.
        rests = [r for r in outcomes[1:] if r.mode in AT_REST and o.sweep.startswith(r.sweep)
                 and ("image" in r.mode) == ("image" in o.mode) and r is not o]  # fmt: skip
        rest = max(rests, key=lambda r: len(r.sweep), default=None)
        speed = o.per_hour / anchor.per_hour
        err = o.scores["error"] / anchor.scores["error"]
        line = (f"{label}, {o.mode}, {o.sweep}, {o.dial}: {speed:.2f}x the anchor's samples per rig-hour (goal >= "
                f"{THROUGHPUT_GOAL:g}x: {'met' if speed >= THROUGHPUT_GOAL else 'NOT met'}), error at equal rig time "
                f"{err:.2f}x (goal <= {ERROR_GOAL:g}x: {'met' if err <= ERROR_GOAL else 'NOT met'})")  # fmt: skip
        if rest is not None:
            line += (f"; against the same sweep at rest: rig time {_x(o.rig_time_s, rest.rig_time_s)}, error at "
                     f"equal rig time {_x(o.scores['error'], rest.scores['error'])}")  # fmt: skip
        lines.append(line)
    return lines


def record_section(args: argparse.Namespace, machine: str, table: str, notes: list[str], lines: list[str]) -> None:
    """Write the ``continuous_scan`` section of docs/benchmarks.md from the run's ``args``, table, notes, verdicts."""
    options = " --quick" if args.quick else ""
    options += f" --points {args.points}" if args.points != 30 else ""
    options += f" --seed {args.seed}" if args.seed != 1 else ""
    quick = ("**These are `--quick` figures** (two scan speeds; no dense, settling or GRBL rows): a smoke run, not "
             "the full bench.\n\n") if args.quick else ""  # fmt: skip
    record(
        "continuous_scan", "Continuous scans against stop-and-go", options, machine + ".",
        quick + f"Each material measured end to end on the simulated Dynamixel rig (simulator seed {args.seed}, one "
        f"noise realisation), every reading a 4 px ROI of a {POINT_RESOLUTION} px camera at SNR {SNR:g}, "
        f"references every 25 points at SNR {REFERENCE_SNR:g}. **Anchor**: bench/image_mode's stop-and-go grid "
        f"of {args.points} points in the planner's order. **Scan sweep** (`scan_design`): runs along the camera "
        "joint (light arm at 15/40/65 deg, stage tilt 0 or -35 deg, roll 0; the camera stepping over every angle "
        f"clockwise of the light where both zeniths stay within {MAX_THETA:.0f} deg), serpentine, kept in that "
        "order (`order = false`); measured at rest (`motion = \"stop\"`) and with `motion = \"continuous\"` at each "
        "`scan_speed_deg_s` of the dial. A continuous run measures the first point of each scan run at rest, as "
        "the runner does, and scans the rest: 'scanned' counts journal records with a `scan` key. The anchor's "
        "grid itself barely scans (the notes say how many of its points sit in runs along one joint): its "
        "neighbours differ in several joints. The scan sweep's joint angles are whole servo counts (scans "
        "now aim a run's last frame where the device comes to rest, `ScanLink.stops_at`; any run that still "
        "waits out the move timeout is left out with a note). 'auto speed' leaves `scan_speed_deg_s` out: each "
        "scan run then goes as fast as its axis, its frames' blur (half a step) and the camera's pace allow, and "
        "is measured at rest where scanning would be slower (rig.run.planning.scans). The image rows read the "
        "same sweep in image mode (at rest and scanned) on image_mode's camera. The row 'exposure from the pass "
        "at rest' scans at auto speed with `exposure_from` naming the same sweep's run at rest "
        "(rig.run.measuring.exposure_ahead): each frame's exposure planned from the pass's reading nearest its "
        "directions instead of the previous frame's (a scan along a lobe otherwise gives its dim flank the "
        "exposure of the bright point before it); that pass's own rig time is not in the row's.\n\n"
        "Rig time is the simulated clock's `run_time_s` (moves, settling, exposures, references). **Equal rig "
        "time**, fits, scores and 'honest' are bench/image_mode's (`bench._modes`): each run is cut in time "
        "order at the anchor's rig time, the points measured by then are fitted with the material's own model "
        "and effective errors, and scored against the true material (relative cosine-weighted RMS BRDF error "
        f"over 4000 pairs up to {MAX_THETA:.0f} deg; shape error after the best scale per channel). Within 1/2/3 "
        "SE: readings against the true material's mean over their footprint and blur (`model.fit.footprint`, "
        "what the rig measures; the fits predict the same) with their own errors, and with the "
        "directions' angular variance at the true material added (the ROI's footprint and, for a scanned point, "
        "the blur of its motion, (speed x exposure)^2 / 12 on the camera joint); 'honest' judges the former. "
        "ScanTooFast: the warnings a run raised (at most one per scan run) and the largest blur (deg) they name. "
        "CPU: this process's seconds for the run and its fit.",
        table,
        "What the scan saves and what it costs, as measured here:\n\n"
        + "\n".join(f"- {line}" for line in lines)
        + "\n\nStop-and-go pays, at every point, a deceleration, an acceleration, the runner's wait for the "
        "servos to report in position and `[link] settle_s`; a scan pays none of these between the points of a "
        "run, but crosses the run at `scan_speed_deg_s`, at most 30 deg/s, where a stop-and-go move cruises at "
        "the axis's top speed (60 deg/s here). So on 20 deg steps the scan only draws level with stop-and-go near "
        "the top of the dial, and at slow speeds it costs many times the rig time; on the dense sweep (four "
        "times the points per run, 5 deg steps) each stop-and-go move is too short to reach top speed and the "
        "stops dominate, which is where the scan pays: continuous scans pay only with many points per run. The "
        "simulated rig does not settle (`settle_s = 0`); the settling rows add "
        "`settle_s` after every stop, a real rig's cost, which the scan avoids at every scanned point. A "
        "scanned frame costs blur (speed x exposure over the frame, in its angular variance) and is exposed once, "
        "planned from the previous frame's level at a quarter of saturation (stop-and-go brackets up to five frames). "
        "Exposures here are milliseconds to a "
        "few tens of ms, so the blur is a fraction of a degree even at 30 deg/s: ScanTooFast (blur over half the "
        "step) needs steps of a degree or two, or the long exposures of a dim sample or a high SNR. Where every "
        "point is kept at equal rig time (the fast rows), compare the scanned rows' error with the same sweep at rest "
        "alongside their shape error and honesty: the matte's shape error is nil, so any gap in its error is the "
        "scale, i.e. the draw of noise, not the blur.\n\n"
        "In point mode every capture is one sample, so a scan changes samples per rig-hour only by the rig time "
        f"a point takes: the {THROUGHPUT_GOAL:g}x goal is not in reach of scans alone (image mode's many tiles "
        "per capture are; continuous + image rows appear here once the capture table takes the pair). Every "
        f"figure is one noise realisation: the readings' relative error is about 1 / SNR = {1 / SNR:.0%}, so a "
        "fit of some 30 of them has a scale uncertain by a few tenths of a percent, and error differences of "
        "that size between rows (the matte's, whose shape any fit gets, above all) are one draw's luck; "
        "`--seed` draws another. Scanned rows are not bit-reproducible either: two runs of this bench with the "
        "same seed gave some scanned rows rig times a few tenths of a second apart and errors tens of percent "
        "apart, where the stop-and-go rows agreed to the digit (the cause is not pinned down here: a scan's timing "
        "on the simulated bus varies between runs).",
        "Notes:\n\n" + "\n".join(f"- {n}" for n in notes),
    )  # fmt: skip
