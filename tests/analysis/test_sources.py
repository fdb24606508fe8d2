"""What gonio analyze accepts besides a run directory: an adaptive sweep's directory (finished or not), its samples
table, a samples table on its own; and the run's [metadata] on the report."""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

import pytest

from analysis.analyze import load_and_fit
from analysis.ladder import parse_models
from analysis.result import AnalysisError
from gonio import cli
from model.fit.spec import LAMBERT
from rig.run.adaptive.sweep import AdaptiveSettings, run_adaptive
from tests.run_helpers import sim_rig

pytestmark = pytest.mark.mitsuba

SETTINGS = AdaptiveSettings(budget=14, initial=8, batch=6, candidates=600, target_snr=50.0)
METADATA = {"sample": "white tile", "operator": "T. Est", "notes": "adaptive source test"}


@pytest.fixture(scope="module")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sources") / "adaptive"
    rig = sim_rig(camera={"resolution": [64, 64], "roi": [30, 30, 34, 34]}, metadata={"operator": "T. Est"})
    sweep_keys = {k: METADATA[k] for k in ("sample", "notes")}  # the sweep's [metadata], laid over the rig's
    run_adaptive(rig, out, LAMBERT, SETTINGS, log=lambda _: None, metadata=sweep_keys)
    return out


def fit(source: Path):  # type: ignore[no-untyped-def]
    return load_and_fit(source, models=parse_models("lambert"), starts=1)


def test_an_adaptive_directory_and_its_table_are_analysed_as_the_whole_sweep(sweep: Path) -> None:
    a = fit(sweep)
    assert a.source.kind == "adaptive" and a.source.state == "finished" and a.source.warning is None
    assert a.source.measured == a.samples.n == 14 and a.source.planned == 14
    assert dict(a.source.metadata) == METADATA
    b = fit(sweep / "samples.csv")  # its table routes to the sweep, so the truth and metadata come along
    assert b.source.kind == "adaptive" and (b.samples.value == a.samples.value).all()
    assert [r.label for r in b.references] == ["simulated material (truth)"]


def test_a_samples_table_alone_is_analysed(sweep: Path, tmp_path: Path) -> None:
    alone = tmp_path / "mine.csv"
    shutil.copy(sweep / "samples.csv", alone)
    a = fit(alone)
    assert a.source.kind == "table" and a.source.measured == 14 and a.source.warning is None
    assert (a.samples.value == fit(sweep).samples.value).all()
    parquet = fit(sweep / "round-00" / "samples.parquet")  # a Parquet table: typed, the same values as its CSV
    assert parquet.source.kind == "table" and parquet.samples.n == 8
    cut = tmp_path / "cut.csv"
    cut.write_text("".join(alone.read_text().splitlines(keepends=True)[:3])[:-40] + "\n")
    with pytest.raises(AnalysisError, match="line 3 has no"):
        fit(cut)


def test_an_unfinished_adaptive_sweep_is_analysed_as_far_as_it_got(sweep: Path, tmp_path: Path) -> None:
    killed = tmp_path / "killed"
    shutil.copytree(sweep, killed)
    for p in (killed / "samples.csv", killed / "round-01" / "samples.csv", killed / "round-01" / "status.json"):
        p.unlink()
    journal = killed / "round-01" / "journal.jsonl"
    journal.write_text("".join(journal.read_text().splitlines(keepends=True)[:4]))  # a reference and 3 points
    state = json.loads((killed / "adaptive.json").read_text())
    (killed / "adaptive.json").write_text(json.dumps({**state, "state": "running"}))
    a = fit(killed)
    assert a.source.kind == "adaptive" and a.samples.n == 8 + 3
    assert a.source.warning is not None and "adaptive sweep not finished" in a.source.warning
    assert f"gonio adaptive --resume {killed}" in a.source.warning


def test_the_report_of_an_adaptive_sweep_heads_with_its_metadata(sweep: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "report"
    assert cli.main(["analyze", str(sweep), "--out", str(out), "--models", "lambert", "--starts", "1", "--quiet"]) == 0
    html = (out / "index.html").read_text()
    for key, value in METADATA.items():
        assert f"<tr><th>{key}</th><td>{value}</td></tr>" in html
    assert f"adaptive sweep {sweep}" in html
    assert json.loads((out / "fit.json").read_text())["source"]["metadata"] == METADATA
    with open(sweep / "samples.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 14


@pytest.mark.parametrize(("content", "what"), [("", "is empty (no header, no rows)"),
                                               ("theta_i_deg,brdf_r\n", "has a header but no rows")])  # fmt: skip
def test_an_empty_table_is_named_as_empty_alone_or_in_an_adaptive_sweep(
    sweep: Path, tmp_path: Path, content: str, what: str
) -> None:
    alone = tmp_path / "mine.csv"
    alone.write_text(content)
    with pytest.raises(AnalysisError, match=rf"mine\.csv: {re.escape(what)}; expected a samples table"):
        fit(alone)
    copy = tmp_path / "adaptive"
    shutil.copytree(sweep, copy)
    (copy / "samples.csv").write_text(content)
    with pytest.raises(AnalysisError, match=rf"samples\.csv: {re.escape(what)}.*round-\* still hold every point"):
        fit(copy)
