"""The adaptive sweep (rig/run/adaptive/sweep.py): its candidates, first round, and a whole run on the simulated rig."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest

from gonio.cli import main
from model.fit.design import brdf_error, error_pairs
from model.fit.spec import LAMBERT, lambert_ggx
from rig.instrument.kinematics import solve_degrees
from rig.run.adaptive.state import AdaptiveStateError
from rig.run.adaptive.sweep import (
    AdaptiveSettings,
    Round,
    candidate_points,
    resume_adaptive,
    run_adaptive,
    space_filling,
)
from rig.run.config.files import material_from
from rig.run.config.sweeps import directions_to_half_diff
from tests.run_helpers import reference_relative_errors, sim_rig

PLASTIC = {"model": "CookTorrance", "rho_d": [0.5, 0.12, 0.08], "alpha": 0.1, "distribution": "ggx",
           "fresnel": "dielectric", "eta": 1.5}  # fmt: skip


def test_candidates_are_reachable_isotropic_pairs_that_include_the_specular_lobe() -> None:
    rig = sim_rig()
    pts = candidate_points(rig.geometry, 3000, max_theta_deg=70.0, seed=1)
    assert 1500 < len(pts) <= 3000
    assert np.all(pts[:, [0, 2]] <= 70.0) and np.all(pts[:, 1] == 0.0)
    assert np.all((pts[:, 3] >= 0.0) & (pts[:, 3] <= 180.0))
    assert np.all(solve_degrees(rig.geometry, pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3]).reachable)
    theta_h = directions_to_half_diff(pts)[:, 0]
    # Cosine-random pairs alone put ~1 % of pairs within 5 deg of the mirror direction; the lobe half, many more.
    assert np.mean(theta_h < 5.0) > 0.1


def test_the_first_round_spreads_over_the_half_difference_domain() -> None:
    pts = candidate_points(sim_rig().geometry, 3000, seed=2)
    hd = directions_to_half_diff(pts)
    x = np.stack([hd[:, 0] / 90, hd[:, 1] / 90, np.abs(hd[:, 2]) / 180], axis=-1)

    def min_gap(idx: np.ndarray) -> float:
        d = np.linalg.norm(x[idx][:, None] - x[idx][None], axis=-1)
        return float(d[np.triu_indices(len(idx), 1)].min())

    picked = space_filling(pts, 20)
    assert len(set(picked.tolist())) == 20
    random_gaps = [min_gap(np.random.default_rng(s).choice(len(pts), 20, replace=False)) for s in range(20)]
    assert min_gap(picked) > max(random_gaps)


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="initial"):
        AdaptiveSettings(budget=10, initial=20)
    with pytest.raises(ValueError, match="reference_snr"):
        AdaptiveSettings(reference_snr=0.0)


def test_reference_snr_sets_the_reference_readings_of_every_round(tmp_path: Path) -> None:
    rig = sim_rig(camera={"resolution": [64, 64], "roi": [30, 30, 34, 34]}, reference={"target_snr": 100.0})
    base = AdaptiveSettings(budget=14, initial=8, batch=6, candidates=600, target_snr=50.0)
    run_adaptive(rig, tmp_path / "rig", LAMBERT, base, log=lambda _: None)
    better = AdaptiveSettings(budget=14, initial=8, batch=6, candidates=600, target_snr=50.0, reference_snr=1500.0)
    run_adaptive(rig, tmp_path / "set", LAMBERT, better, log=lambda _: None)
    as_rig, as_set = reference_relative_errors(tmp_path / "rig"), reference_relative_errors(tmp_path / "set")
    # Round 0 (8 points, every 6) reads three times, round 1 twice.
    assert len(as_rig) == len(as_set) == 5
    # The goal sets the photon noise; the journal's error is the larger of that and a 16-pixel scatter, which
    # scatters itself. The rig's own goal of 100, which its bright tile overshoots, stays well above 1/1500.
    assert np.median(as_set) <= 1.05 / 1500.0 and np.all(as_set <= 1.5 / 1500.0)
    assert np.all(as_rig > 1.5 / 1500.0)


def test_an_adaptive_sweep_runs_rounds_refits_and_lowers_its_predicted_error(tmp_path: Path) -> None:
    rig = sim_rig(PLASTIC, camera={"resolution": [128, 128], "roi": [62, 62, 66, 66]},
                  reference={"target_snr": 400.0})  # fmt: skip
    truth = material_from(rig)
    pairs = error_pairs(1000, max_theta_deg=70.0)
    seen: list[Round] = []
    settings = AdaptiveSettings(budget=32, initial=12, batch=10, candidates=1500)
    result = run_adaptive(rig, tmp_path / "ad", lambert_ggx("dielectric"), settings, pairs=pairs,
                          on_round=seen.append, log=lambda _: None)  # fmt: skip
    assert [r.captures for r in result.rounds] == [12, 22, 32] and seen == result.rounds
    assert all((r.directory / "samples.csv").exists() for r in result.rounds)
    assert result.rig_time_s == pytest.approx(sum(r.rig_time_s for r in result.rounds)) and result.rig_time_s > 0
    predicted = [r.predicted_error for r in result.rounds[1:]]
    assert predicted[1] < predicted[0]
    final = result.rounds[-1].fit
    assert brdf_error(final.model, truth, pairs) < 0.02
    assert final.param("alpha")[0] == pytest.approx(0.1, abs=4 * final.param("alpha")[1] + 1e-3)
    # The later rounds look where a glossy lobe is informative: close to the mirror direction.
    assert result.table is not None
    with open(result.table, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 32 and {r["round"] for r in rows} == {"0", "1", "2"}
    merged = pq.read_table(result.table.with_suffix(".parquet"))  # the same rows, typed, beside the CSV
    assert merged.num_rows == 32 and merged.column("round").to_pylist() == [int(r["round"]) for r in rows]
    assert merged.column("brdf_r").to_pylist() == [float(r["brdf_r"]) for r in rows]
    later = np.array([[float(r[k]) for k in ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")]
                      for r in rows if r["round"] != "0"])  # fmt: skip
    assert np.mean(directions_to_half_diff(later)[:, 0] < 10.0) >= 0.3
    doc = json.loads((tmp_path / "ad" / "adaptive.json").read_text())
    assert [d["captures"] for d in doc["rounds"]] == [12, 22, 32]
    # Each round is its own run with its own noise: the rounds' first reference readings are distinct draws.
    firsts = {tuple(next(json.loads(line) for line in open(r.directory / "journal.jsonl")
                         if '"reference"' in line)["reading"]) for r in result.rounds}  # fmt: skip
    assert len(firsts) == 3
    with pytest.raises(ValueError, match="not empty"):
        run_adaptive(rig, tmp_path / "ad", lambert_ggx("dielectric"), settings)


SMALL = AdaptiveSettings(budget=14, initial=8, batch=6, candidates=600, target_snr=50.0)


def small_rig() -> Any:
    return sim_rig(camera={"resolution": [64, 64], "roi": [30, 30, 34, 34]},
                   metadata={"sample": "white tile", "operator": "T. Est"})  # fmt: skip


def without_utc(table: Path) -> list[dict[str, str]]:
    with open(table, newline="") as fh:
        return [{k: v for k, v in row.items() if k != "utc"} for row in csv.DictReader(fh)]


def kill_in_round_one(whole: Path, copy: Path, keep_lines: int) -> None:
    """``copy``: ``whole`` as a SIGKILL in round 1 would leave it (round 1's journal cut, no tables, no status)."""
    shutil.copytree(whole, copy)
    for name in ("samples.csv", "samples.parquet", "samples.schema.json"):
        (copy / name).unlink()
        (copy / "round-01" / name).unlink()
    (copy / "round-01" / "status.json").unlink()
    journal = copy / "round-01" / "journal.jsonl"
    journal.write_text("".join(journal.read_text().splitlines(keepends=True)[:keep_lines]))
    state = json.loads((copy / "adaptive.json").read_text())
    (copy / "adaptive.json").write_text(json.dumps({**state, "state": "running", "rounds": state["rounds"][:1]}))


@pytest.fixture(scope="module")
def whole_sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("adaptive") / "whole"
    run_adaptive(small_rig(), out, LAMBERT, SMALL, log=lambda _: None, metadata={"notes": "resume test"})
    return out


def test_an_interrupted_adaptive_sweep_resumes_to_the_uninterrupted_table(
    whole_sweep: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    state = json.loads((whole_sweep / "adaptive.json").read_text())
    assert state["state"] == "finished" and state["model"] == "lambert" and state["settings"]["budget"] == 14
    assert state["metadata"] == {"sample": "white tile", "operator": "T. Est", "notes": "resume test"}
    killed = tmp_path / "killed"
    kill_in_round_one(whole_sweep, killed, keep_lines=4)
    points_before = sum('"kind":"point"' in line for line in open(killed / "round-01" / "journal.jsonl"))
    assert 0 < points_before < 6
    # gonio resume on an adaptive directory resumes the sweep (round 1 from its journal, then the merge).
    assert main(["resume", str(killed), "--quiet"]) == 0, capsys.readouterr().err
    assert without_utc(killed / "samples.csv") == without_utc(whole_sweep / "samples.csv")
    assert json.loads((killed / "adaptive.json").read_text())["state"] == "finished"
    journal = [json.loads(line) for line in open(killed / "round-01" / "journal.jsonl")]
    assert sum(r.get("kind") == "point" for r in journal) == 6  # only the missing points were measured
    assert json.loads((killed / "samples.schema.json").read_text())["metadata"] == state["metadata"]
    # Once finished there is nothing to resume; the message says so.
    assert main(["adaptive", "--resume", str(killed)]) == 2
    assert "finished" in capsys.readouterr().err


def test_a_resume_with_changed_settings_is_refused(whole_sweep: Path, tmp_path: Path) -> None:
    killed = tmp_path / "changed"
    kill_in_round_one(whole_sweep, killed, keep_lines=4)
    state = json.loads((killed / "adaptive.json").read_text())
    state["settings"]["seed"] = 5  # another candidate pool: round 0 on disk is not what this sweep would measure
    (killed / "adaptive.json").write_text(json.dumps(state))
    with pytest.raises(AdaptiveStateError, match="round-00: its run measured other points"):
        resume_adaptive(killed, lambda name: LAMBERT)
    with pytest.raises(AdaptiveStateError, match="not an adaptive sweep's directory"):
        resume_adaptive(tmp_path, lambda name: LAMBERT)
