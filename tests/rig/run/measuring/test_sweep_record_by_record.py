"""A short sweep on the simulated rig writes, record by record, the journal and table it wrote before issue 21.

The controller's per-point work was made cheaper (scalar kinematics and rounding, a faster planner search and
one-kind merge variance, ROI shortcuts, one camera hand-off per exposure and one for a point's darks, a faster
journal walk, the journal's records kept rather than parsed again; the bracket check's settings and frames
without dataclasses.replace and the reading's lists without atleast_1d were undone in issue 29). Each shortcut
has its own bit-for-bit test; this one runs the same sweep twice, once as it is and once with every shortcut replaced
by the implementation it replaced (kept in the tests), and compares what the two runs wrote.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition.cfa import HdrImage
from acquisition.roi import Box, RoiError, RoiReading
from rig.run.backends.hardware import dynamixel_options
from rig.run.config.files import parse, rig_config, sweep_config
from rig.run.config.schema import RigFile, SweepFile
from rig.run.measuring.runner import Runner, RunOptions
from rig.run.session import capture_settings, make_plan, manifest
from rig.run.storage import formats as store_formats
from rig.run.storage.store import RunStore
from simulator.from_config import spec_from
from simulator.rig import SimulatedRig
from tests.acquisition.test_exposure_oracle import (
    oracle_min_snr,
    oracle_roi_snr,
    oracle_shortest,
    reference_merged_variance,
)
from tests.rig.run.measuring.test_check_shortcuts import reference_roi_check
from tests.rig.run.measuring.test_reading_shortcuts import reference_level_of, reference_reading
from tests.rig.run.measuring.test_runner_rounding import reference as reference_round
from tests.rig.run.measuring.test_runner_rounding import reference_as_list
from tests.rig.run.storage.test_store_jsonable import reference_jsonable


def reference_reduce_hdr_roi(hdr: HdrImage, roi: Box, *, on_flagged: Any = "exclude") -> RoiReading:
    got = reference_reading(hdr.radiance, hdr.variance, roi, flags=hdr.saturated, dark=hdr.dark, policy=on_flagged)
    if isinstance(got, str):  # the reference gives the message the code under test must raise
        raise RoiError(got)
    return got


def reference_shoot(camera: Any, exposure_s: float) -> Any:
    camera.set_exposure(exposure_s)
    return camera.capture()


def reference_darks(
    camera: Any, exposures: tuple[float, ...], n: int
) -> tuple[dict[float, list[Any]], tuple[float, ...]]:
    take_dark = getattr(camera, "capture_dark", None)
    if n == 0 or take_dark is None:
        return {}, ()
    darks: dict[float, list[Any]] = {}
    taken: list[float] = []
    for t in sorted(set(exposures)):
        applied = camera.set_exposure(t).exposure_s
        darks[applied] = [take_dark() for _ in range(n)]
        taken += [applied] * n
    return darks, tuple(taken)


def refuse_exact(value: Any) -> Any:
    raise store_formats.NotExactJson


def as_before(m: pytest.MonkeyPatch) -> None:
    """Every shortcut of issue 21 replaced by what it replaced."""
    import acquisition.exposure.plan as plan
    import acquisition.exposure.snr as snr
    import rig.instrument.kinematics as kinematics
    import rig.run.measuring.measure as measure
    import rig.run.measuring.runner as runner
    import rig.run.storage.store as store

    m.setattr(plan, "_shortest", oracle_shortest)
    m.setattr(plan, "roi_snr", oracle_roi_snr)
    m.setattr(plan, "single_exposure_min_snr", oracle_min_snr)
    m.setattr(snr, "_merged_variance", reference_merged_variance)
    m.setattr(snr, "_geomspace", lambda lo, hi, num: np.geomspace(lo, hi, num).tolist())
    m.setattr(measure, "reduce_hdr_roi", reference_reduce_hdr_roi)
    m.setattr(measure, "level_of", reference_level_of)
    m.setattr(measure, "_shoot", reference_shoot)
    m.setattr(measure, "_darks", reference_darks)
    m.setattr(measure, "_roi_check", reference_roi_check)
    m.setattr(kinematics, "forward_one", lambda geometry, joints: None)
    m.setattr(runner, "_f", reference_round)
    m.setattr(runner, "_as_list", reference_as_list)
    m.setattr(store, "jsonable", reference_jsonable)
    m.setattr(RunStore, "records_to_read", RunStore.records)
    m.setattr(store, "exact_json", refuse_exact)  # every record by jsonable, its line parsed again
    m.setattr(store, "_encode_line", lambda value: store._dumps(value, separators=(",", ":")))


def sweep_run(where: Path) -> Path:
    """The bench's sweep (bench/sweep.py: planned exposures) over 12 points, into ``where``."""
    rig = rig_config(parse({"reference": {"kind": "none"}, "camera": {"spp": 1}}, RigFile, "<rig>"), "<rig>")
    doc = {"sweep": {"kind": "grid", "theta_i_deg": [10.0, 40.0, 70.0], "theta_o_deg": [5.0, 45.0],
                     "phi_o_deg": [100.0, 180.0], "isotropic": False}, "capture": {}}  # fmt: skip
    sweep = sweep_config(parse(doc, SweepFile, "<sweep>"), "<sweep>")
    plan = make_plan(rig, sweep)
    options = RunOptions(progress=False)
    with SimulatedRig(spec_from(rig)) as sim:
        assert sim.camera is not None
        store = RunStore.create(where, manifest(rig, sweep, plan, options))
        Runner(plan, store, sim.open_link(dynamixel_options(rig)), sim.camera, sim.clock, rig.geometry,
               capture_settings(rig, sweep), options=options).run()  # fmt: skip
        store.close()
    return where


def without_utc(record: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in record.items() if k != "utc"}


def test_the_sweep_writes_what_it_wrote_before(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    now = sweep_run(tmp_path / "now")
    with monkeypatch.context() as m:
        as_before(m)
        before = sweep_run(tmp_path / "before")
    lines_now = (now / "journal.jsonl").read_text().splitlines()
    lines_before = (before / "journal.jsonl").read_text().splitlines()
    assert len(lines_now) == len(lines_before) >= 12
    for a, b in zip(lines_now, lines_before, strict=True):
        # byte for byte once the wall-clock time stamp is cut out
        assert json.dumps(without_utc(json.loads(a))) == json.dumps(without_utc(json.loads(b)))
        assert a.replace(json.loads(a)["utc"], "") == b.replace(json.loads(b)["utc"], "")
    rows_now = list(csv.DictReader((now / "samples.csv").open()))
    rows_before = list(csv.DictReader((before / "samples.csv").open()))
    assert [without_utc(r) for r in rows_now] == [without_utc(r) for r in rows_before]
