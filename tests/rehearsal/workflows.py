"""The hardware workflows a lab runs, each against a rehearsal through gonio's real backends (shared by both links).

Each ``check_*`` drives one workflow end to end in separate processes, as a person at a terminal would: the
rig file is the shipped hardware file with its port and folder pointed at the rehearsal, and an ROI moved
so the rehearsal's sensor is 512 x 384 pixels instead of the 4200 x 2800 the shipped ROI implies (whole-frame
calibrations would take minutes a frame otherwise; the ROI is where the sensor's centre is either way).
``test_rehearsal_dynamixel.py`` and ``test_rehearsal_grbl.py`` call them, one file per link so the two
links run on the suite's two workers side by side.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.rehearsal.harness import Operator, Rehearsal

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = {"dynamixel": ROOT / "examples" / "rig_dynamixel.toml", "grbl": ROOT / "examples" / "rig_grbl.toml"}
#: The shipped ROI's place moved to the centre of a 512 x 384 sensor (see the module docstring).
SMALL_ROI = "[248, 184, 264, 200]"
#: Faster than real time: the controller's polls and the folder camera's waits are real, the rig's are scaled.
SPEED = "50"
#: Eight points and a reference tile every three: long enough to need references in the middle of the run.
SWEEP = """name = "rehearsal grid"

[sweep]
kind = "grid"
theta_i_deg = [15.0, 45.0]
theta_o_deg = [10.0, 35.0]
phi_o_deg = [135.0, 180.0]
isotropic = true

[capture]
target_snr = 100.0
"""

#: ``examples/rig_misaligned.toml``'s [simulation.misalignment], which its controller is not told.
MISALIGNED = {"light_zero_deg": 0.5, "camera_zero_deg": -0.3, "tilt_zero_deg": 0.2, "roll_zero_deg": 0.4,
              "sample_tilt_deg": 0.6, "sample_tilt_azimuth_deg": 30.0, "sample_offset_mm": [1.0, -0.8, 0.5]}


def small_rig(link: str, tmp: Path) -> Path:
    """The shipped hardware rig file of ``link``: the small sensor's ROI, a reference every 3 points, quick polls."""
    from tests.rehearsal.harness import set_keys

    path = tmp / f"shipped_{link}.toml"
    text = set_keys(SHIPPED[link].read_text(), {"roi": SMALL_ROI, "every": "3"})
    # As docs/hardware.md says a rehearsal's controller may: the rehearsal renames each frame in whole.
    path.write_text(text.replace("[camera]\n", "[camera]\nstable_polls = 1\npoll_interval_s = 0.02\n", 1))
    return path


def rehearsal_of(rig: Path, frames: Path, *extra: str) -> Rehearsal:
    """A rehearsal of ``rig`` writing into ``frames`` (not started: use it as a context manager)."""
    return Rehearsal(("--rig", str(rig), "--speed", SPEED, *extra), frames)


def table(run: Path) -> list[dict[str, str]]:
    """A run's samples.csv as rows of text, as a user's script reads it."""
    with (run / "samples.csv").open() as fh:
        return list(csv.DictReader(fh))


#: Columns computed from the reference tile's readings interpolated in the run's time: on a real clock a
#: resumed run was measured at other times than an uninterrupted one, so these differ within their noise.
TIME_CALIBRATED = ("brdf_r", "brdf_g", "brdf_b", "brdf_se_r", "brdf_se_g", "brdf_se_b", "brdf_se_readings_r",
                   "brdf_se_readings_g", "brdf_se_readings_b")  # fmt: skip


def references(run: Path) -> list[dict[str, object]]:
    """The reference readings a run's journal holds, without their times."""
    out = []
    for line in (run / "journal.jsonl").read_text().splitlines():
        record = json.loads(line)
        if record.get("kind") == "reference":
            out.append({k: v for k, v in record.items() if not k.endswith("time_s") and k != "utc"})
    return out


def check_run_interrupt_resume(op: Operator, rig: Path, sweep: Path, tmp: Path) -> tuple[Path, Path]:
    """Plan, run, Ctrl-C a second run at a mid-run reference, resume it: the first run's table; returns both runs."""
    plan = op.run("plan", str(sweep), "--rig", str(rig))
    assert plan.status == 0, plan.output
    assert "Sweep of 8 points: 8 to measure, 0 unreachable" in plan.output
    whole, cut = tmp / "whole", tmp / "cut"
    first = op.run("run", str(sweep), "--rig", str(rig), "--out", str(whole), "--quiet")
    assert first.status == 0, first.output
    assert "measured 8 points (0 from before), 4 reference readings" in first.output
    assert sum("place the reference tile" in p for p in first.prompts) == 4
    stopped = op.run("run", str(sweep), "--rig", str(rig), "--out", str(cut), "--quiet",
                     interrupt_after="before point 3")  # fmt: skip
    assert stopped.status == 130, stopped.output
    assert f"gonio resume {cut}" in stopped.output
    resumed = op.run("resume", str(cut), "--quiet")
    assert resumed.status == 0, resumed.output
    a, b = table(whole), table(cut)
    assert len(a) == len(b) == 8
    for row_a, row_b in zip(a, b, strict=True):
        same = {k: v for k, v in row_a.items() if k != "utc" and k not in TIME_CALIBRATED}
        assert same == {k: row_b[k] for k in same}, f"row {row_a['index']} differs after the resume"
        for channel in "rgb":
            gap = abs(float(row_a[f"brdf_{channel}"]) - float(row_b[f"brdf_{channel}"]))
            assert gap < float(row_a[f"brdf_se_{channel}"]), (row_a["index"], channel, gap)
    # Each reference slot's last reading (a resume reads again the one it was stopped in) is the same.
    last_a = {r["slot"]: r for r in references(whole)}
    last_b = {r["slot"]: r for r in references(cut)}
    assert last_a == last_b
    return whole, cut


def check_analyze(op: Operator, whole: Path, cut: Path, tmp: Path) -> None:
    """``gonio analyze`` of a rehearsed run and of its table alone, and ``gonio batch analyze`` of both runs."""
    report = op.run("analyze", str(whole), "--quiet", "--models", "lambert,lambert_ggx")
    assert report.status == 0, report.output
    assert (whole / "analysis" / "index.html").is_file()
    fit = json.loads((whole / "analysis" / "fit.json").read_text())
    assert fit["chosen"] in ("lambert", "lambert_ggx")
    alone = op.run("analyze", str(cut / "samples.csv"), "--quiet", "--models", "lambert", "--out", str(tmp / "csv"))
    assert alone.status == 0, alone.output
    batch = op.run("batch", "analyze", str(whole), str(cut), "--out", str(tmp / "batch"), "--workers", "1",
                   "--no-dashboard", "--quiet", "--models", "lambert")  # fmt: skip
    assert batch.status == 0, batch.output
    assert (tmp / "batch" / "catalogue.parquet").is_file()


def check_adaptive(op: Operator, rig: Path, tmp: Path) -> None:
    """``gonio adaptive`` stopped after its first round and resumed: every capture of the budget measured."""
    out = tmp / "adaptive"
    args = ("--budget", "8", "--initial", "4", "--batch", "2", "--snr", "30", "--model", "lambert", "--quiet")
    stopped = op.run("adaptive", "--rig", str(rig), "--out", str(out), *args, interrupt_after="round 1:")
    assert stopped.status == 130, stopped.output
    resumed = op.run("adaptive", "--resume", str(out), "--quiet")
    assert resumed.status == 0, resumed.output
    report = op.run("analyze", str(out), "--quiet", "--models", "lambert", "--out", str(tmp / "adaptive-analysis"))
    assert report.status == 0, report.output


def check_camera_calibration(op: Operator, rig: Path, tmp: Path) -> dict[str, object]:
    """``gonio calibrate camera`` with its light and lens cap placed on request; returns the calibration."""
    out = tmp / "camera"
    done = op.run("calibrate", "camera", "--rig", str(rig), "--out", str(out), "--steps", "12", "--flat-frames", "4",
                  "--quiet")  # fmt: skip
    assert done.status == 0, done.output
    asked = [next((k for k in ("uniform, stable light", "cap the lens", "restore the rig") if k in p), p)
             for p in done.prompts]  # fmt: skip
    assert asked == ["uniform, stable light", "cap the lens", "restore the rig"], done.prompts
    calibration: dict[str, object] = json.loads((out / "camera_calibration.json").read_text())
    return calibration


def check_geometry_calibration(op: Operator, rig: Path, out: Path, captures: int,
                               truth: dict[str, object]) -> dict[str, dict[str, object]]:  # fmt: skip
    """``gonio calibrate geometry`` with the board mounted on request: each quantity within 3 standard errors."""
    done = op.run("calibrate", "geometry", "--rig", str(rig), "--out", str(out), "--captures", str(captures))
    assert done.status == 0, done.output
    doc = json.loads((out / "geometry_calibration.json").read_text())
    found = {k: v for k, v in doc.items() if isinstance(v, dict) and "std_error" in v}
    for name, true in truth.items():
        value, error = found[name]["value"], found[name]["std_error"]
        pairs = zip(value, error, true, strict=True) if isinstance(true, list) else [(value, error, true)]
        for v, se, t in pairs:
            assert abs(v - t) <= 3 * se, (name, found[name], true)
    return found


Rehearsed = tuple[Rehearsal, Path, Path]
"""A running rehearsal of a link's shipped rig file, the controller's copy of that file, and a folder to work in."""


class Workflows:
    """The workflows both links run; a link's test file subclasses it as ``Test...`` naming its ``link``."""

    link: str

    @pytest.fixture(scope="class")
    @classmethod
    def rehearsed(cls, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rehearsed]:
        """The link's shipped rig file rehearsed (see the module docstring), once for the class's tests."""
        tmp = tmp_path_factory.mktemp(cls.link)
        shipped = small_rig(cls.link, tmp)
        with rehearsal_of(shipped, tmp / "frames") as reh:
            yield reh, reh.rig_file(shipped, tmp / "rig.toml"), tmp

    def test_the_geometry_calibration_of_the_misaligned_rig(self, tmp_path: Path) -> None:
        # examples/rig_misaligned.toml served on this link with its [simulation] hidden, calibrated through the
        # hardware rig file the rehearsal writes. 18 captures find it within 3 SE as 30 do (largest |z| 2.2-2.3
        # in three runs); at 12 the sample's tilt landed at 3.7-3.9 SE in two runs of four (docs/benchmarks.md).
        written = tmp_path / "rig.toml"
        with rehearsal_of(ROOT / "examples" / "rig_misaligned.toml", tmp_path / "frames", "--link", self.link,
                          "--write-rig", str(written)) as reh:  # fmt: skip
            assert f'kind = "{self.link}"' in written.read_text() and "[simulation" not in written.read_text()
            check_geometry_calibration(Operator(reh, tmp_path), written, tmp_path / "calib", 18, MISALIGNED)

    def test_a_run_stopped_and_resumed_is_analysed(self, rehearsed: Rehearsed) -> None:
        reh, rig, tmp = rehearsed
        sweep = tmp / "sweep.toml"
        sweep.write_text(SWEEP)
        op = Operator(reh, tmp)
        whole, cut = check_run_interrupt_resume(op, rig, sweep, tmp)
        check_analyze(op, whole, cut, tmp)

    def test_an_adaptive_sweep_stopped_and_resumed(self, rehearsed: Rehearsed) -> None:
        reh, rig, tmp = rehearsed
        check_adaptive(Operator(reh, tmp), rig, tmp)

    def test_the_camera_calibration_finds_the_sensor(self, rehearsed: Rehearsed) -> None:
        reh, rig, tmp = rehearsed
        found = check_camera_calibration(Operator(reh, tmp), rig, tmp)["parameters"]
        assert isinstance(found, dict)
        # The rehearsal's sensor is [camera.noise]'s defaults: 4 e-/DN, 3 e- read noise, black at 512 DN.
        for key, truth in (("e_per_dn", 4.0), ("read_noise_e", 3.0), ("black_level_dn", 512.0)):
            assert abs(found[key]["value"] - truth) <= 3 * found[key]["std_error"], (key, found[key])
