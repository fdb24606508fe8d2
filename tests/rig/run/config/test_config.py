"""Rig and sweep files: the shipped examples load, and every mistake names the file, the key and the value."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rig.instrument.sample_surface import SampleShape
from rig.run.config.files import ConfigError, load_rig, load_sweep, material_from, parse, rig_config, sweep_config
from rig.run.config.schema import RigFile, SweepFile, run_metadata
from rig.run.session import make_plan

EXAMPLES = Path(__file__).resolve().parents[4] / "examples"


@pytest.mark.parametrize("name", ["rig_simulated.toml", "rig_dynamixel.toml", "rig_simulated_grbl.toml"])
def test_example_rigs_load(name: str) -> None:
    rig = load_rig(EXAMPLES / name)
    assert [a.name for a in rig.axes] == list(rig.geometry.joint_names)


def test_a_simulated_grbl_rig_gets_lettered_steppers_homing_apart_and_coordinated_plans() -> None:
    rig = load_rig(EXAMPLES / "rig_simulated_grbl.toml")
    light, camera, tilt, roll = rig.axes
    assert [a.address for a in rig.axes] == ["X", "Y", "Z", "A"]
    assert light.units_per_degree == camera.units_per_degree == pytest.approx(3200 / 360)
    # Switches one pull-off beyond the end each arm homes to: the light's top, the camera's bottom.
    assert (light.direction, light.zero_offset_deg) == (1, light.max_deg + 1.0)
    assert (camera.direction, camera.zero_offset_deg) == (-1, camera.min_deg - 1.0)
    # The tilt table changed its gear: the switch moves with it (one motor degree is a third of a joint degree).
    assert tilt.gear_ratio == 3.0 and tilt.zero_offset_deg == pytest.approx(tilt.max_deg + 1.0 / 3.0)
    assert tilt.max_speed_deg_s == 30.0 and roll.max_speed_deg_s == 60.0
    sweep = load_sweep(EXAMPLES / "sweep_in_plane.toml")
    grbl, servos = make_plan(rig, sweep), make_plan(load_rig(EXAMPLES / "rig_simulated.toml"), sweep)
    assert grbl.paths is not None and grbl.paths.coordinated  # straight G1 moves, timed and checked as such
    assert servos.paths is not None and not servos.paths.coordinated
    assert len(grbl.points) == len(servos.points)  # the same reachable points as the servo rig


@pytest.mark.parametrize("name", ["rig_simulated.toml", "rig_simulated_grbl.toml", "rig_misaligned.toml",
                                  "rig_simulated_raw.toml"])  # fmt: skip
def test_a_rig_rebuilt_from_its_manifest_has_the_same_axes(name: str) -> None:
    # A resume rebuilds the rig from the manifest's dump, where every default is written out: a key the file left
    # out must mean the same there (the simulated GRBL's tilt table, which names its gear ratio only, once got the
    # generic zero of -180 deg on resume instead of its switch beyond the limit, and measured on another step grid).
    rig = load_rig(EXAMPLES / name)
    dumped = rig.file.model_dump(mode="json", exclude_none=True)  # what rig.run.session.manifest stores
    again = rig_config(parse(dumped, RigFile, "manifest.json rig"), "manifest.json")
    assert again.axes == rig.axes


def test_the_sample_table_gives_the_rig_its_shape_in_metres(tmp_path: Path) -> None:
    assert load_rig(EXAMPLES / "rig_simulated.toml").sample_shape == SampleShape()
    rig = load_rig(EXAMPLES / "rig_simulated_sphere.toml")
    assert rig.sample_shape.kind == "sphere" and rig.sample_shape.radius_m == pytest.approx(0.02)
    cylinder = load_rig(_write(tmp_path, "[sample]\nshape = 'cylinder'\nradius_mm = 7\n"))
    assert cylinder.sample_shape == SampleShape("cylinder", 0.007)


def test_rig_file_values_reach_the_objects() -> None:
    rig = load_rig(EXAMPLES / "rig_dynamixel.toml")
    assert rig.geometry.light_radius_m == 0.6 and rig.geometry.min_separation_deg == 10.0
    tilt = next(a for a in rig.axes if a.name == "tilt")
    assert tilt.address == 3 and tilt.gear_ratio == 3.0
    assert rig.file.camera.roi == (2000, 1300, 2200, 1500)


@pytest.mark.parametrize(("name", "count"), [("sweep_in_plane.toml", 33), ("sweep_grid.toml", None),
                                             ("sweep_rusinkiewicz.toml", None)])  # fmt: skip
def test_example_sweeps_load(name: str, count: int | None) -> None:
    sweep = load_sweep(EXAMPLES / name)
    assert sweep.directions_deg.ndim == 2 and sweep.directions_deg.shape[1] == 4
    assert len(sweep.directions_deg) > 0
    if count is not None:
        assert len(sweep.directions_deg) == count


def _write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


RIG_MISTAKES = [
    ("[geometry]\nlight_radius_m = -0.5\n", r"geometry\.light_radius_m = -0\.5: expected a value greater than 0"),
    (
        "[geometry]\nlite_radius_m = 0.5\n",
        r"geometry\.lite_radius_m = 0\.5: unknown key; expected one of .*light_radius_m",
    ),
    ("[link]\nkind = 'dynamixel'\n", r"\[link\] a dynamixel link needs port"),
    ("[link]\nkind = 'can'\n", r"link\.kind = 'can': expected a value 'simulated', 'dynamixel' or 'grbl'"),
    ("[simulation]\nlink = 'can'\n", r"simulation\.link = 'can': expected a value 'dynamixel' or 'grbl'"),
    ("[simulation]\nlink = 'grbl'\n[axes.light]\nid = 1\n", r"axes\.light\.id = 1: expected letter \(a GRBL axis"),
    ("[simulation]\nlink = 'grbl'\n[axes.light]\nletter = 'Y'\n", r"axes: address 'Y' is used by two joints"),
    ("[axes.light]\nletter = 'X'\n", r"axes\.light\.letter = 'X': expected id \(a Dynamixel id"),
    ("[axes.light]\nid = 'one'\n", r"axes\.light\.id = 'one': expected a valid integer"),
    ("[axes.light]\nidd = 3\n",
     r"axes\.light\.idd = 3: unknown key; expected one of backlash_deg, direction, gear_ratio, id,"),
    ("[axes.arm]\nid = 1\n", r"axes\.arm: no such joint in layout 'four_axis'; expected one of light, camera"),
    ("[axes.light]\nid = 1\n[axes.camera]\nid = 1\n", r"address 1 is used by two joints"),
    ("[geometry]\nsample_width_m = 2.0\n", r"\[geometry\] RigGeometry\.light_radius_m = 0\.5 m.*half-diagonal"),
    ("[camera]\nresolution = [32, 32, 3]\n", r"camera\.resolution = \[32, 32, 3\]"),
    ("[camera]\nroi = [0, 0, 64, 64]\n", r"camera\.roi = \[0, 0, 64, 64\]: expected a box .* inside 32x32 pixels"),
    ("[reference]\nalbedo = 1.5\n", r"reference\.albedo = 1\.5: expected a value less than or equal to 1"),
    ("[simulation.material]\nmodel = 'Glass'\n", r"simulation\.material\.model = 'Glass': expected one of .*Lambert"),
    ("[simulation.material]\nmodel = 'Lambert'\nrho_d = 3.0\n", r"simulation\.material: "),
    ("name = 5\n", r"name = 5: expected a valid string"),
    ("[sample]\nradius_mm = 20.0\n", r"\[sample\] radius_mm = 20: a flat sample has no radius; expected no radius_mm"),
    ("[sample]\nshape = 'sphere'\n", r"\[sample\] shape = 'sphere': a sphere needs radius_mm"),
    ("[sample]\nshape = 'cone'\nradius_mm = 5.0\n", r"sample\.shape = 'cone': expected a value 'flat', 'sphere'"),
    ("[sample]\nshape = 'cylinder'\nradius_mm = 0.0\n", r"sample\.radius_mm = 0\.0: expected a value greater than 0"),
    ("[sample]\nshape = 'sphere'\nradius_mm = 300.0\n", r"sample\.radius_mm = 300\.0: expected a value less than"),
    ("[sample]\nshape = 'sphere'\nradius_mm = '5'\n", r"sample\.radius_mm = '5': expected a valid number \(> 0"),
    ("[geometry]\nlight_radius_m = 0.2\n[sample]\nshape = 'sphere'\nradius_mm = 120.0\n",
     r"sample\.radius_mm = 120: a sphere of that radius reaches 0\.24 m from the arms' axis.*less than 100 mm"),
    ("[geometry\n", r"not valid TOML"),
]


@pytest.mark.parametrize(("text", "message"), RIG_MISTAKES)
def test_rig_mistakes_name_file_key_and_value(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        material_from(load_rig(path))
    assert str(path) in str(info.value)


SWEEP_MISTAKES = [
    ("[capture]\ntarget_snr = 100.0\n", r"sweep: missing; this key is required"),
    ("[sweep]\nkind = 'grid'\ntheta_i_deg = [0.0]\n", r"\[sweep\] a 'grid' sweep needs theta_o_deg"),
    ("[sweep]\nkind = 'spiral'\n", r"sweep\.kind = 'spiral': expected a value 'grid', 'in_plane'"),
    ("[sweep]\nkind = 'list'\npoints = [[0.0, 0.0, 30.0]]\n",
     r"sweep\.points\[0\]: too few items; expected at least 4"),
    ("[sweep]\nkind = 'list'\npoints = [[0.0, 0.0, 95.0, 0.0]]\n", r"sweep: .*row 0"),
    ("[sweep]\nkind = 'grid'\ntheta_i_deg = [0.0]\ntheta_o_deg = [10.0]\npoints = [[0.0, 0.0, 1.0, 0.0]]\n",
     r"points has no meaning in a 'grid' sweep"),
    ("[sweep]\nkind = 'in_plane'\ntheta_i_deg = ['30']\ntheta_o_deg = [10.0]\n",
     r"sweep\.theta_i_deg\[0\] = '30': expected a valid number"),
    ("[sweep]\nkind = 'in_plane'\ntheta_i_deg = [30.0]\ntheta_o_deg = [10.0]\n[capture]\nexposures_s = [0.0]\n",
     r"capture\.exposures_s\[0\] = 0\.0: expected a value greater than 0"),
    ("[sweep]\nkind = 'in_plane'\ntheta_i_deg = [30.0]\ntheta_o_deg = [10.0]\n[capture]\nsnr = 5.0\n",
     r"capture\.snr = 5\.0: unknown key; expected one of .*target_snr"),
]  # fmt: skip


@pytest.mark.parametrize(("text", "message"), SWEEP_MISTAKES)
def test_sweep_mistakes_name_file_key_and_value(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        load_sweep(path)
    assert str(path) in str(info.value)


def test_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope\.toml: no such file"):
        load_rig(tmp_path / "nope.toml")


# -- fuzzing: whatever a file holds, loading it gives a valid config or a ConfigError, nothing else ---------------

toml_scalars = st.one_of(
    st.integers(-10**6, 10**6), st.floats(allow_nan=False), st.text(max_size=8), st.booleans(),
    st.lists(st.floats(-200, 200, allow_nan=False), max_size=4),
)  # fmt: skip


def _mutate(doc: dict[str, Any], path: list[str], value: Any) -> dict[str, Any]:
    """Set (or add) a key somewhere in a nested document."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in doc.items()}
    node = out
    for key in path[:-1]:
        child = node.get(key)
        node[key] = dict(child) if isinstance(child, dict) else {}
        node = node[key]
    node[path[-1]] = value
    return out


RIG_DOC = tomllib.loads((EXAMPLES / "rig_simulated.toml").read_text())
SWEEP_DOC = tomllib.loads((EXAMPLES / "sweep_in_plane.toml").read_text())
rig_keys = st.sampled_from([
    ["geometry", "layout"], ["geometry", "light_radius_m"], ["geometry", "min_separation_deg"], ["link", "kind"],
    ["link", "move_timeout_s"], ["camera", "resolution"], ["camera", "spp"], ["camera", "noise", "e_per_dn"],
    ["reference", "albedo"], ["reference", "every"], ["simulation", "seed"], ["simulation", "material", "alpha"],
    ["axes", "light", "id"], ["axes", "tilt", "gear_ratio"], ["bogus"], ["geometry", "limits", "tilt"],
    ["sample", "shape"], ["sample", "radius_mm"],
])  # fmt: skip
sweep_keys = st.sampled_from([
    ["sweep", "kind"], ["sweep", "theta_i_deg"], ["sweep", "theta_o_deg"], ["sweep", "points"],
    ["sweep", "isotropic"], ["capture", "target_snr"], ["capture", "max_frames"], ["capture", "exposures_s"],
    ["name"], ["capture", "bogus"], ["metadata", "sample"], ["metadata", "batch"],
])  # fmt: skip


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rig_keys, toml_scalars)
def test_fuzzed_rig_files_load_or_say_why(path: list[str], value: Any) -> None:
    doc = _mutate(RIG_DOC, path, value)
    try:
        material_from(rig_config(parse(doc, RigFile, "fuzz.toml"), "fuzz.toml"))
    except ConfigError as exc:
        assert str(exc).startswith("fuzz.toml") and len(str(exc)) > len("fuzz.toml: ")


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sweep_keys, toml_scalars)
def test_fuzzed_sweep_files_load_or_say_why(path: list[str], value: Any) -> None:
    doc = _mutate(SWEEP_DOC, path, value)
    try:
        sweep_config(parse(doc, SweepFile, "fuzz.toml"), "fuzz.toml")
    except ConfigError as exc:
        assert str(exc).startswith("fuzz.toml") and len(str(exc)) > len("fuzz.toml: ")


def test_metadata_tables_are_kept_merged_and_checked(tmp_path: Path) -> None:
    rig, sweep = load_rig(EXAMPLES / "rig_simulated.toml"), load_sweep(EXAMPLES / "sweep_in_plane.toml")
    assert rig.file.metadata.as_dict() == {"lab": "simulation"}
    meta = sweep.file.metadata
    assert meta.sample == "rough gold (simulated)" and meta.operator == "gonio examples" and meta.notes
    assert run_metadata(rig.file, sweep.file) == {"lab": "simulation", **meta.as_dict()}
    doc = {"sweep": {"kind": "list", "points": [[0.0, 0.0, 30.0, 180.0]]},
           "metadata": {"sample": "tile", "batch": 7, "tags": ["a", "b"], "when": tomllib.loads("d = 2026-12-01")["d"]}}
    got = parse(doc, SweepFile, "m.toml").metadata.as_dict()
    assert got == {"sample": "tile", "batch": 7, "tags": ["a", "b"], "when": "2026-12-01"}
    bad = tmp_path / "bad.toml"
    for text, message in [
        ('[metadata]\nsample = 3', "bad.toml: metadata.sample = 3: expected a valid string"),
        ("[metadata]\nsetup = { lamp = 'halogen' }", "bad.toml: [metadata] setup = {'lamp': 'halogen'}: expected a "
                                                     "string, number, boolean, date or a list of those"),
        ("[metadata]\nlevel = nan", "bad.toml: [metadata] level = nan: expected a finite number"),
    ]:
        bad.write_text(text + '\n[sweep]\nkind = "list"\npoints = [[0.0, 0.0, 30.0, 180.0]]\n')
        with pytest.raises(ConfigError) as err:
            load_sweep(bad)
        assert str(err.value).startswith(f"{tmp_path}/" + message), str(err.value)


def _model_classes() -> list[type]:
    import model
    from model.base import Model

    return [c for n in sorted(dir(model)) if isinstance(c := getattr(model, n), type) and issubclass(c, Model)
            and c is not Model]  # fmt: skip


@pytest.mark.parametrize("cls", _model_classes(), ids=lambda c: c.__name__)
def test_a_misspelt_material_parameter_names_the_models_parameters_and_the_closest(tmp_path: Path, cls: type) -> None:
    import inspect

    names = list(inspect.signature(cls).parameters)
    wanted = names[0]
    typo = wanted + "x"  # rho_d -> rho_dx, alpha -> alphax
    path = _write(tmp_path, f"[simulation.material]\nmodel = '{cls.__name__}'\n{typo} = 0.5\n")
    with pytest.raises(ConfigError) as info:
        load_rig(path)  # at load, before any run directory exists, not when the simulator builds the scene
    text = str(info.value)
    assert text.startswith(f"{path}: simulation.material.{typo} = 0.5: {cls.__name__} has no parameter {typo!r}")
    assert f"its parameters are {', '.join(names)}" in text
    assert f"did you mean {wanted!r}?" in text


def test_lambert_with_rho_suggests_rho_d(tmp_path: Path) -> None:
    path = _write(tmp_path, "[simulation.material]\nmodel = 'Lambert'\nrho = 0.5\n")
    with pytest.raises(ConfigError, match=r"Lambert has no parameter 'rho'; its parameters are rho_d; did you mean "
                       r"'rho_d'\?"):  # fmt: skip
        load_rig(path)


DYNAMIXEL_RIG = """[link]
kind = "dynamixel"
port = "/dev/ttyUSB0"
[axes.light]
id = 1
{light}
[axes.camera]
id = 2
[axes.tilt]
id = 3
gear_ratio = 3.0
{tilt}
[axes.roll]
id = 4
[reference]
kind = "manual"
"""


@pytest.mark.parametrize(
    ("light", "tilt", "message"),
    [
        ("max_speed_deg_s = 720.0", "", r"axes\.light\.max_speed_deg_s = 720: an XM430-W350 takes at most 274\.8 "
         r"deg/s \(its Velocity Limit, 200 x 0\.229 rev/min\); expected at most 274\.8 deg/s for this joint"),
        ("", "max_speed_deg_s = 100.0", r"axes\.tilt\.max_speed_deg_s = 100 \(x gear_ratio 3 = 300 at the servo\): "
         r"an XM430-W350 takes at most 274\.8 deg/s .*; expected at most 91\.6 deg/s for this joint"),
        ("max_accel_deg_s2 = 1e6", "", r"axes\.light\.max_accel_deg_s2 = 1e\+06: an XM430-W350 takes at most 703104 "
         r"deg/s\^2 .*32767"),
    ],
)  # fmt: skip
def test_a_dynamixel_axis_faster_than_the_servo_is_refused_naming_key_value_and_limit(
    tmp_path: Path, light: str, tilt: str, message: str
) -> None:
    path = _write(tmp_path, DYNAMIXEL_RIG.format(light=light, tilt=tilt))
    with pytest.raises(ConfigError, match=message):
        load_rig(path)


def test_the_servo_limits_the_rig_file_allows_are_the_virtual_xm430s() -> None:
    """At the limit the (virtual) servo takes the profile; just beyond it answers Data Limit Error."""
    import dataclasses

    from rig.instrument.clock import ManualClock
    from rig.instrument.links.base import LinkError
    from rig.instrument.links.dynamixel import DynamixelLink
    from rig.instrument.links.dynamixel_table import X_SERIES
    from simulator.dynamixel import open_virtual_bus

    fastest = X_SERIES.max_speed_deg_s / 3.0
    at_limit = DYNAMIXEL_RIG.format(light="", tilt=f"max_speed_deg_s = {fastest!r}")
    rig = rig_config(parse(tomllib.loads(at_limit), RigFile, "rig.toml"), "rig.toml")
    beyond = tuple(dataclasses.replace(a, max_speed_deg_s=fastest * 1.01) if a.name == "tilt" else a
                   for a in rig.axes)  # fmt: skip
    with pytest.raises(ConfigError, match="max_speed_deg_s"):
        rig_config(parse(tomllib.loads(DYNAMIXEL_RIG.format(light="", tilt=f"max_speed_deg_s = {fastest * 1.01!r}")),
                         RigFile, "rig.toml"), "rig.toml")  # fmt: skip
    clock = ManualClock()
    with open_virtual_bus(ids=(1, 2, 3, 4), baudrate=1_000_000, clock=clock) as bus:
        DynamixelLink.open(bus.port, rig.axes, clock=clock, latency_timer_ms=60.0).shutdown()
        with pytest.raises(LinkError, match="Data Limit"):
            DynamixelLink.open(bus.port, beyond, clock=clock, latency_timer_ms=60.0).shutdown()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[link]\nbaudrate = 1e30\n", r"link\.baudrate = 1e\+30: expected a valid integer \(> 0 and <= 20000000\)"),
        ("[link]\nbaudrate = 100000000\n", r"link\.baudrate = 100000000: expected a value less than or equal to 2"),
        ("[simulation]\nseed = 18446744073709551617\n",
         r"simulation\.seed = 18446744073709551617: expected a value less than or equal to 4294967295"),
        ("[simulation]\nseed = 1.5\n", r"simulation\.seed = 1\.5: expected a valid integer \(>= 0 and <= 4294967295\)"),
        ("[camera.noise]\ne_per_dn = 1e-300\n",
         r"camera\.noise\.e_per_dn = 1e-300: expected a value greater than or equal to 0\.001"),
        ("[camera.noise]\nfull_well_e = 1e300\n", r"camera\.noise\.full_well_e = 1e\+300: expected a value less than"),
        ("[geometry]\nlight_radius_m = 1e300\n", r"geometry\.light_radius_m = 1e\+300: expected a value less than"),
        ("[camera]\nmax_exposure_s = 1e300\n", r"camera\.max_exposure_s = 1e\+300: expected a value less than"),
        ("[reference]\nevery = 10000000000\n", r"reference\.every = 10000000000: expected a value less than"),
        ("[simulation]\nlight_intensity_w_sr = 1e300\n", r"simulation\.light_intensity_w_sr = 1e\+300: expected"),
        ("[simulation]\ntime_scale = 1e300\n", r"simulation\.time_scale = 1e\+300: expected a value less than"),
        ("[axes.light]\nid = 1\ntolerance_deg = 1e300\n", r"axes\.light\.tolerance_deg = 1e\+300: expected a"),
    ],
)  # fmt: skip
def test_extreme_numbers_are_refused_naming_key_value_and_range(tmp_path: Path, text: str, message: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        load_rig(path)
    assert str(info.value).startswith(str(path))
