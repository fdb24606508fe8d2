"""An adaptive sweep's capture modes (rig/run/adaptive/modes.py): image rounds, auto, and captures, not rows."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from model.fit.spec import LAMBERT
from rig.run.adaptive.modes import round_choice
from rig.run.adaptive.state import AdaptiveStateError
from rig.run.adaptive.sweep import AdaptiveSettings, resume_adaptive, run_adaptive
from rig.run.measuring.mode_choice import MIN_SCAN_POINTS
from rig.run.session import make_plan
from rig.run.storage.store import RunStore
from tests.rig.run.adaptive.test_adaptive import kill_in_round_one, without_utc
from tests.run_helpers import in_plane_sweep, sim_rig

#: Three captures, then three more: each round a run of its own.
SMALL = AdaptiveSettings(budget=6, initial=3, batch=3, candidates=600, target_snr=50.0)


def _rows(table: Path) -> list[dict[str, str]]:
    with open(table, newline="") as fh:
        return list(csv.DictReader(fh))


def _points(directory: Path) -> int:
    return sum(r["kind"] == "point" for r in RunStore.read(directory).records())


def test_the_mode_settings_are_checked_by_the_sweep_file_s_rules() -> None:
    cases: list[tuple[dict[str, Any], str]] = [
        ({"mode": "frame"}, "mode = 'frame'"),
        ({"motion": "scan"}, "motion = 'scan'"),
        ({"tile_px": 4}, "tile_px = 4 has no meaning with mode = 'point'"),
        ({"mode": "image", "tile_px": 0}, "tile_px = 0"),
        ({"scan_speed_deg_s": 3.0}, "scan_speed_deg_s = 3 has no meaning"),
        ({"motion": "continuous", "scan_speed_deg_s": 45.0}, "at most 30"),
    ]
    for bad, match in cases:
        with pytest.raises(ValueError, match=match):
            replace(SMALL, **bad)
    ok = replace(SMALL, mode="auto", tile_px=4, motion="continuous", scan_speed_deg_s=3.0)
    assert (ok.mode, ok.tile_px, ok.motion, ok.scan_speed_deg_s) == ("auto", 4, "continuous", 3.0)
    assert replace(SMALL, mode="image", motion="continuous").motion == "continuous"  # image frames scan too


@pytest.mark.mitsuba
def test_an_image_mode_sweep_counts_captures_and_keeps_every_tile(tmp_path: Path) -> None:
    rig = sim_rig(camera={"resolution": [64, 64]})
    settings = replace(SMALL, mode="image", tile_px=8)
    said: list[str] = []
    result = run_adaptive(rig, tmp_path / "ad", LAMBERT, settings, log=said.append)
    # The budget is in captures: two rounds of three poses, each many rows.
    assert [r.captures for r in result.rounds] == [3, 6]
    assert [_points(r.directory) for r in result.rounds] == [3, 3]
    assert all(r.mode == "image" and r.motion == "stop" for r in result.rounds)
    assert result.table is not None
    rows = _rows(result.table)
    assert len(rows) == result.rounds[-1].samples and len(rows) >= 4 * 6
    assert all(r["tile"] != "" for r in rows)
    assert len({(r["round"], r["index"]) for r in rows}) == 6
    assert all(json.loads((r.directory / "manifest.json").read_text())["sweep"]["capture"]["tile_px"] == 8
               for r in result.rounds)  # fmt: skip
    doc = json.loads((tmp_path / "ad" / "adaptive.json").read_text())
    rounds = [(d["captures"], d["mode"], d["motion"]) for d in doc["rounds"]]
    assert rounds == [(3, "image", "stop"), (6, "image", "stop")]
    assert doc["rounds"][-1]["samples"] == len(rows)
    assert said[0].startswith("round 0: 3 captures (3 in image mode, stop: ")
    # Every tile is fitted with its own errors: the Lambertian albedo within its error of the truth, 0.5.
    fit = result.rounds[-1].fit
    for name, value, se in zip(fit.names, fit.values, fit.std_errors, strict=True):
        assert abs(value - 0.5) < 4 * se + 0.01, (name, value, se)


@pytest.fixture(scope="module")
def auto_sweep(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str]]:
    out = tmp_path_factory.mktemp("auto") / "whole"
    said: list[str] = []
    run_adaptive(sim_rig(camera={"resolution": [128, 128]}), out, LAMBERT, replace(SMALL, mode="auto"),
                 log=said.append)  # fmt: skip
    return out, said


@pytest.mark.mitsuba
def test_auto_measures_the_first_round_in_image_mode_and_later_ones_in_point_mode(
    auto_sweep: tuple[Path, list[str]],
) -> None:
    out, said = auto_sweep
    doc = json.loads((out / "adaptive.json").read_text())
    rounds = [(d["captures"], d["mode"], d["motion"]) for d in doc["rounds"]]
    assert rounds == [(3, "image", "stop"), (6, "point", "stop")]
    assert "first round" in doc["rounds"][0]["mode_reason"] and "tiles" in doc["rounds"][0]["mode_reason"]
    assert "later round" in doc["rounds"][1]["mode_reason"]
    rows = _rows(out / "samples.csv")
    first, later = [r for r in rows if r["round"] == "0"], [r for r in rows if r["round"] == "1"]
    assert len(first) > 3 * 16 and all(r["tile"] != "" for r in first)
    assert len(later) == 3 and all(r["tile"] == "" for r in later)
    assert said[0].startswith("round 0: 3 captures (3 in image mode") and "(point mode)" in said[1]
    assert said[2].startswith("round 1: 6 captures (3 in point mode, stop: 3 samples)")


@pytest.mark.mitsuba
def test_an_auto_sweep_keeps_its_settings_and_resumes_as_it_chose(
    auto_sweep: tuple[Path, list[str]], tmp_path: Path
) -> None:
    whole, _ = auto_sweep
    state = json.loads((whole / "adaptive.json").read_text())
    assert {k: state["settings"][k] for k in ("mode", "tile_px", "motion", "scan_speed_deg_s")} == {
        "mode": "auto", "tile_px": None, "motion": "stop", "scan_speed_deg_s": None}  # fmt: skip
    killed = tmp_path / "killed"
    kill_in_round_one(whole, killed, keep_lines=2)
    result = resume_adaptive(killed, lambda name: LAMBERT, log=lambda _: None)
    assert [(r.mode, r.captures) for r in result.rounds] == [("image", 3), ("point", 6)]
    assert without_utc(killed / "samples.csv") == without_utc(whole / "samples.csv")
    # Settings that would measure round 0 another way are refused, not continued.
    changed = tmp_path / "changed"
    kill_in_round_one(whole, changed, keep_lines=2)
    doc = json.loads((changed / "adaptive.json").read_text())
    doc["settings"]["mode"] = "point"
    (changed / "adaptive.json").write_text(json.dumps(doc))
    with pytest.raises(AdaptiveStateError, match="round-00: its run was measured with mode image, motion stop"):
        resume_adaptive(changed, lambda name: LAMBERT, log=lambda _: None)


@pytest.mark.mitsuba
def test_a_state_written_before_the_mode_settings_resumes_as_point_mode_at_rest(tmp_path: Path) -> None:
    rig = sim_rig(camera={"resolution": [64, 64], "roi": [30, 30, 34, 34]})
    whole = tmp_path / "whole"
    run_adaptive(rig, whole, LAMBERT, AdaptiveSettings(budget=4, initial=2, batch=2, candidates=600,
                                                        target_snr=50.0), log=lambda _: None)  # fmt: skip
    killed = tmp_path / "killed"
    kill_in_round_one(whole, killed, keep_lines=2)
    doc = json.loads((killed / "adaptive.json").read_text())
    for key in ("mode", "tile_px", "motion", "scan_speed_deg_s"):
        del doc["settings"][key]
    (killed / "adaptive.json").write_text(json.dumps(doc))
    result = resume_adaptive(killed, lambda name: LAMBERT, log=lambda _: None)
    assert [(r.mode, r.motion, r.captures) for r in result.rounds] == [("point", "stop", 2), ("point", "stop", 4)]
    assert without_utc(killed / "samples.csv") == without_utc(whole / "samples.csv")


def test_auto_scans_a_point_round_only_where_its_plan_has_a_long_run_and_the_settings_allow_it() -> None:
    rig = sim_rig(reference={"every": 0})
    line = make_plan(rig, in_plane_sweep([20.0], [30.0, 35.0, 40.0, 45.0, 50.0]))
    scattered = make_plan(rig, in_plane_sweep([20.0, 40.0], [30.0, 60.0]))
    allowed = replace(SMALL, mode="auto", motion="continuous", scan_speed_deg_s=3.0)
    choice = round_choice(rig, allowed, 1, line)
    assert (choice.mode, choice.motion) == ("point", "continuous") and choice.longest_scan == 5
    assert round_choice(rig, allowed, 1, scattered).motion == "stop"
    assert round_choice(rig, replace(SMALL, mode="auto"), 1, line).motion == "stop"
    assert f">= {MIN_SCAN_POINTS}" in choice.reason
    # The first round's image mode scans by the same rule.
    camera = sim_rig(camera={"resolution": [128, 128]}, reference={"every": 0})
    first = round_choice(camera, allowed, 0, make_plan(camera, in_plane_sweep([20.0], [30.0, 35.0, 40.0, 45.0, 50.0])))
    assert (first.mode, first.motion, first.tile_px) == ("image", "continuous", 8)
    # Fixed modes are what the settings say, round after round.
    fixed = replace(SMALL, mode="point", motion="continuous")
    assert [(c.mode, c.motion) for c in (round_choice(rig, fixed, i, scattered) for i in (0, 1))] == [
        ("point", "continuous")] * 2  # fmt: skip

