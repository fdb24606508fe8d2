"""Exposure planned ahead ([capture] exposure_model / exposure_from): the planner's rules, then scans on the rig."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from model.geometry import degrees_to_vector
from model.lambert import Lambert
from rig.run.config.files import ConfigError
from rig.run.measuring.exposure_ahead import OFF_FACTOR, ExposureAhead
from rig.run.measuring.exposure_sources import PASS_REACH_DEG, ModelSource, PassSource, load_sources
from rig.run.measuring.measure import Level


@dataclasses.dataclass(frozen=True)
class Table:
    """A source whose signal is a function of theta_o alone (a stand-in for a model, in its own units)."""

    values: dict[float, float]
    name: str = "model"
    prior_scale: float | None = None

    def signal(self, d: tuple[float, float, float, float]) -> np.ndarray | None:
        v = self.values.get(d[2])
        return None if v is None else np.array([v, 2 * v, 3 * v])

    def template(self, d: tuple[float, float, float, float]) -> dict[str, Any] | None:
        return None


def _level(scale: float) -> Level:
    """A colour level: channel means 1:2:3 times ``scale``, peak 1.5 x the brightest, darkest pixel 0.5 x the mean."""
    means = (scale, 2 * scale, 3 * scale)
    return Level(4.5 * scale, 2 * scale, scale, 16, means)


def _at(theta_o: float) -> tuple[float, float, float, float]:
    return (20.0, 0.0, theta_o, 0.0)


def test_a_model_plans_nothing_before_the_run_calibrates_its_scale_then_predicts_in_counts() -> None:
    ahead = ExposureAhead([Table({0.0: 1.0, 10.0: 30.0})])
    assert ahead.plan(_at(0.0), None) == (None, "metered")  # no scale, no level: the first point is metered
    first = _level(500.0)  # measured: 500 counts/s where the model says 1 -> scale 500
    assert ahead.plan(_at(0.0), first) == (first, "previous")
    assert ahead.observe(_at(0.0), first) == []
    level, source = ahead.plan(_at(10.0), first)
    assert source == "model" and level is not None
    # 30 x the signal, each channel; the previous level's shape: peak over brightest channel, dark over mean
    assert level.channel_means == pytest.approx((15000.0, 30000.0, 45000.0))
    assert level.peak == pytest.approx(1.5 * 45000.0) and level.dark == pytest.approx(0.5 * level.mean)
    assert level.mean == pytest.approx(30000.0) and level.n_pixels == 16
    # Where the model has nothing to say, the previous point plans the next
    assert ahead.plan(_at(55.0), first) == (first, "previous")


def test_a_prediction_off_by_more_than_the_factor_is_reported_and_its_source_sits_out_the_next_point() -> None:
    ahead = ExposureAhead([Table({0.0: 1.0, 5.0: 2.0, 10.0: 3.0})])
    ahead.observe(_at(0.0), _level(100.0))
    assert ahead.observe(_at(5.0), _level(200.0 * 0.5 * OFF_FACTOR)) == []  # off by x2: fine
    missed = ahead.observe(_at(10.0), _level(300.0 / (1.5 * OFF_FACTOR)))  # darker than predicted by x6 (scale 141)
    assert [m.source for m in missed] == ["model"] and missed[0].factor < 1 / OFF_FACTOR
    assert ahead.plan(_at(5.0), _level(1.0))[1] == "previous"
    ahead.observe(_at(5.0), _level(2.0 * math.exp(float(np.median(np.log([100.0, 200.0, 50.0 / 3.0]))))))
    assert ahead.plan(_at(0.0), _level(1.0))[1] == "model"  # right again: back in


def test_an_earlier_pass_plans_even_the_first_point_and_hands_over_to_a_model_beyond_its_reach() -> None:
    n = 3
    passed = PassSource(np.array([degrees_to_vector(20.0, 0.0)] * n), np.array([degrees_to_vector(t, 0.0) for t in
                        (0.0, 10.0, 20.0)]), ((10.0, 20.0, 30.0), (40.0, 80.0, 120.0), (1.0, 2.0, 3.0)),
                        ({"peak": 45.0, "mean": 20.0, "dark": 10.0, "n_pixels": 16}, None, None), "run")  # fmt: skip
    ahead = ExposureAhead([passed, Table({40.0: 1.0})])
    level, source = ahead.plan(_at(1.0), None)  # the pass's level at 0 deg, at its own scale: counts/s
    assert source == "pass" and level is not None and level.mean == pytest.approx(20.0)
    assert ahead.plan(_at(10.0), None) == (None, "metered")  # no level kept there (a samples.csv): nothing to shape
    assert ahead.plan(_at(20.0 + PASS_REACH_DEG + 1.0), _level(1.0))[1] == "previous"  # beyond reach, no model scale
    ahead.observe(_at(40.0), _level(7.0))
    assert ahead.plan(_at(40.0), _level(1.0))[1] == "model"


def test_a_grey_level_is_planned_from_the_signals_mean_and_replay_rebuilds_the_state() -> None:
    table = Table({0.0: 1.0, 5.0: 4.0, 10.0: 8.0})  # colour signals (1:2:3), a grey camera's levels
    grey = Level(30.0, 20.0, 10.0, 9)
    live = ExposureAhead([table])
    records = []
    for pos, (t, mean) in enumerate([(0.0, 20.0), (5.0, 70.0), (10.0, 5.0)]):
        if pos == 2:  # scale: the median of 20 / 2 and 70 / 8, times the signal's mean (16)
            level, source = live.plan(_at(t), grey)
            assert source == "model" and level is not None and level.channel_means == ()
            assert level.mean == pytest.approx(math.sqrt(10.0 * 8.75) * 16.0)
        lvl = dataclasses.replace(grey, mean=mean)
        assert bool(live.observe(_at(t), lvl)) == (pos == 2)  # the last is x30 darker than predicted
        records.append({"kind": "point", "position": pos, "target_deg": list(_at(t)), "level": lvl.as_dict(),
                        "lower_bound": False, "dark": False})  # fmt: skip
    assert live.plan(_at(5.0), grey) == (grey, "previous")
    again = ExposureAhead([table])
    again.replay(reversed(records))  # in plan order, whatever the order given
    assert [t.off for t in again.tracks] == [t.off for t in live.tracks] == [True]
    assert [r.tolist() for r in again.tracks[0].ratios] == [r.tolist() for r in live.tracks[0].ratios]


def test_a_models_signal_is_its_brdf_times_the_incidence_cosine_and_nothing_past_the_horizon() -> None:
    source = ModelSource(Lambert(0.5), "m.json")
    got = source.signal((60.0, 0.0, 30.0, 180.0))
    assert got is not None and float(np.mean(got)) == pytest.approx(0.5 / math.pi * 0.5)
    assert source.signal((90.0, 0.0, 30.0, 0.0)) is None


# -- the files, checked before anything moves ---------------------------------------------------------


def _model_file(tmp_path: Path, doc: Any, name: str = "fit.json") -> str:
    path = tmp_path / name
    if isinstance(doc, bytes):
        path.write_bytes(doc)
    else:
        path.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return name


def test_fit_json_and_material_json_both_load(tmp_path: Path) -> None:
    model = {"model": "Lambert", "params": {"rho_d": 0.3}}
    fit = _model_file(tmp_path, {"chosen": "lambert", "model": model}, "fit.json")
    material = _model_file(tmp_path, {**model, "facts": {}}, "material.json")
    for name in (fit, material):
        (source,) = load_sources(tmp_path / "sweep.toml", None, name)
        assert isinstance(source, ModelSource) and isinstance(source.model, Lambert)


@pytest.mark.parametrize(("doc", "message"), [
    (None, "no such file"),
    ("{not json", "is not JSON"),
    (b"\x89PNG\r\n\x1a\n\xff\xfe", "cannot read"),
    ({"chosen": "lambert"}, "holds no model"),
    ({"model": "Sparkle", "params": {}}, "Sparkle"),
    ({"model": "Lambert", "params": {"rho_d": "a lot"}}, "rho_d"),
])  # fmt: skip
def test_a_bad_model_file_is_an_input_error_naming_sweep_key_file_and_what_was_expected(
    tmp_path: Path, doc: Any, message: str
) -> None:
    name = "missing.json" if doc is None else _model_file(tmp_path, doc)
    with pytest.raises(ConfigError, match=message) as err:
        load_sources(tmp_path / "sweep.toml", None, name)
    text = str(err.value)
    assert "sweep.toml: capture.exposure_model = " in text and name in text
    assert err.value.exit_code == 2


def test_a_run_directory_as_the_model_says_where_its_fit_is(tmp_path: Path) -> None:
    (tmp_path / "coarse").mkdir()
    with pytest.raises(ConfigError, match=r"is a directory .*coarse/analysis/fit\.json.*exposure_from"):
        load_sources(tmp_path / "sweep.toml", None, "coarse")


def test_a_bad_pass_is_an_input_error_naming_what_was_expected(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep.toml"
    with pytest.raises(ConfigError, match=r"capture\.exposure_from = 'nowhere': no such run directory or file"):
        load_sources(sweep, "nowhere", None)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="not a readable run directory"):
        load_sources(sweep, "empty", None)
    (tmp_path / "t.csv").write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,reading_r\n1,2,3,4,5\n")
    with pytest.raises(ConfigError, match=r"t\.csv lacks column\(s\) reading_g, reading_b"):
        load_sources(sweep, "t.csv", None)
    head = "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,reading_r,reading_g,reading_b\n"
    (tmp_path / "t.csv").write_text(head + "1,2,3,4,5,6,x\n")
    with pytest.raises(ConfigError, match=r"t\.csv, line 2: .*numbers"):
        load_sources(sweep, "t.csv", None)
    (tmp_path / "t.csv").write_text(head)
    with pytest.raises(ConfigError, match="holds no measured point"):
        load_sources(sweep, "t.csv", None)
