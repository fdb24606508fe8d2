"""Load rig and sweep files (TOML), validate them strictly, and turn them into the objects the runner uses.

Every mistake raises ``ConfigError`` with the file, the key (as a dotted TOML path), the bad value and
what was expected; unknown keys are errors. The schema, with units and defaults, is ``rig.run.config.schema``.

One file past 400 lines on purpose: loading, the did-you-mean errors and the conversion to the runner's
objects follow the schema's tables one by one; the schema itself is schema.py.
"""

from __future__ import annotations

import dataclasses
import datetime
import inspect
import re
import tomllib
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ValidationError

import model
from model.base import Model
from model.errors import InputError
from model.plain import json_copy
from model.spelling import did_you_mean
from rig.instrument.alignment import Alignment
from rig.instrument.axis import Axis
from rig.instrument.calibration_file import (
    RESIDUAL_LIMIT,
    CalibrationFileError,
    GeometryCalibration,
    read_geometry_calibration,
)
from rig.instrument.geometry import GeometryError, JointLimits, RigGeometry
from rig.instrument.links.dynamixel_table import X_SERIES
from rig.instrument.sample_surface import SampleShape
from rig.run import registry
from rig.run.config.camera import Camera as CameraTable
from rig.run.config.camera import camera_keys
from rig.run.config.fitted_for import changes, fitted_for
from rig.run.config.schema import AxisTable, RigFile, SweepFile

FloatArray = npt.NDArray[np.float64]
M = TypeVar("M", bound=BaseModel)


class ConfigError(InputError, ValueError):
    """A rig or sweep file is unreadable or invalid; the message names the file, key, value and expectation."""


def _key(loc: tuple[int | str, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _table_model(model: type[BaseModel], loc: tuple[int | str, ...]) -> type[BaseModel] | None:
    """The model of the table that holds the key at ``loc`` (None where ``loc`` leaves the schema)."""
    current: Any = model
    parts = list(loc[:-1])
    while parts and current is not None:
        part = parts.pop(0)
        info = current.model_fields.get(part) if isinstance(part, str) else None
        ann = info.annotation if info is not None else None
        if typing.get_origin(ann) is dict:
            # A table of named tables such as [axes.<joint>]: skip the free name, go on in its value's model.
            ann, parts = typing.get_args(ann)[1], parts[1:]
        current = ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None
    return current


def _allowed_keys(model: type[BaseModel], loc: tuple[int | str, ...]) -> list[str]:
    """The keys the table at ``loc`` accepts (for an unknown-key message)."""
    current = _table_model(model, loc)
    return sorted(current.model_fields) if current is not None else []


#: pydantic's error types that say only what type was wanted; the key's bounds are added to them.
_TYPE_ERRORS = ("int_type", "int_from_float", "int_parsing", "float_type", "finite_number", "float_parsing")


def _range(model: type[BaseModel], loc: tuple[int | str, ...]) -> str:
    """`` from 1 to 20000000`` (or ``>= 0`` ...) for the key at ``loc`` if its schema bounds it, else ``""``."""
    if not loc or not isinstance(loc[-1], str):
        return ""
    current = _table_model(model, loc)
    info = current.model_fields.get(loc[-1]) if current is not None else None
    if info is None:
        return ""
    metadata = list(info.metadata)
    for arg in typing.get_args(info.annotation):  # an optional key: Annotated[float, Field(...)] | None
        metadata += list(getattr(arg, "__metadata__", ()))
        for inner in getattr(arg, "__metadata__", ()):
            metadata += list(getattr(inner, "metadata", ()))
    bounds = {type(m).__name__: getattr(m, type(m).__name__.lower()) for m in metadata
              if type(m).__name__ in ("Gt", "Ge", "Lt", "Le")}  # fmt: skip
    shown = {k: str(v) if isinstance(v, int) else f"{v:g}" for k, v in bounds.items()}
    lo = f">= {shown['Ge']}" if "Ge" in shown else f"> {shown['Gt']}" if "Gt" in shown else ""
    hi = f"<= {shown['Le']}" if "Le" in shown else f"< {shown['Lt']}" if "Lt" in shown else ""
    return f" ({' and '.join(x for x in (lo, hi) if x)})" if lo or hi else ""


def _clean(loc: tuple[int | str, ...]) -> tuple[int | str, ...]:
    # Union members add their type's name to the path ("constrained-float", "tuple[...]"): not TOML keys.
    return tuple(p for p in loc if isinstance(p, int) or re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", p))


def _messages(path: Path, model: type[BaseModel], err: ValidationError) -> str:
    lines = []
    errors = err.errors()
    locs = [_clean(tuple(e["loc"])) for e in errors]
    for e, loc in zip(errors, locs, strict=True):
        if any(len(other) > len(loc) and other[: len(loc)] == loc for other in locs):
            continue  # a union's member reported something more precise under this key
        key = _key(loc)
        if e["type"] == "extra_forbidden":
            allowed = _allowed_keys(model, loc)
            hint = did_you_mean(loc[-1] if loc else None, allowed)
            lines.append(f"{path}: {key} = {_short(e['input'])}: unknown key; expected one of {', '.join(allowed)}"
                         f"{hint}")
        elif e["type"] == "missing" and loc and isinstance(loc[-1], int):
            lines.append(f"{path}: {_key(loc[:-1])}: too few items; expected at least {loc[-1] + 1}")
        elif e["type"] == "missing":
            lines.append(f"{path}: {key}: missing; this key is required")
        elif e["type"] == "value_error":
            # Checks across keys of one table: the message names the keys itself.
            lines.append(f"{path}: [{key}] {str(e['msg']).removeprefix('Value error, ')}")
        else:
            msg = str(e["msg"])
            msg = "a value " + msg.removeprefix("Input should be ") if msg.startswith("Input should be ") else msg
            msg = msg.replace("a value a ", "a ").replace("a value an ", "an ")
            shown = _short(json_copy(e["input"])) if not isinstance(e["input"], dict) else "(table)"
            head = f"{path}: {key} = {shown}: expected "
            text = msg[0].lower() + msg[1:] if msg else "a valid value"
            if e["type"] in _TYPE_ERRORS:
                text += _range(model, loc)
            if e["type"] == "literal_error":
                text += did_you_mean(e["input"], re.findall(r"'([^']*)'", str(e.get("ctx", {}).get("expected", ""))))
            same = [i for i, line in enumerate(lines) if line.startswith(head)]
            if same:  # one key failing every member of a union: say what each member wanted
                lines[same[0]] += f" or {text}"
            else:
                lines.append(head + text)
    return "\n".join(lines)


def _load(path: str | Path, model: type[M]) -> M:
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{p}: not a usable TOML file: tables or arrays nested too deeply to read") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.strerror}") from None
    return parse(data, model, p)


def parse(data: Mapping[str, Any], model: type[M], path: str | Path = "<memory>") -> M:
    """Validate a parsed TOML document against a schema model; ConfigError names file, key and value."""
    try:
        return model.model_validate(dict(data))
    except ValidationError as exc:
        raise ConfigError(_messages(Path(path), model, exc)) from None


def as_table(cfg: RigFile | SweepFile) -> dict[str, Any]:
    """A validated file as the JSON table it came from: the keys it gave, without the schema's defaults.

    Which keys a file gives is part of what it says: a [camera] key of another backend is refused,
    [camera.noise] beside a camera calibration is an error, a simulated GRBL axis without direction or
    zero_offset_deg is homed to its limit. A manifest that dumped the defaults too (the simulated camera's
    resolution into a folder camera's table, say) was refused by its own run on reading it back.
    """
    return cfg.model_dump(mode="json", exclude_unset=True)


def saved_rig(data: Mapping[str, Any], where: str | Path) -> RigFile:
    """A rig table saved by a run (manifest.json, adaptive.json) validated, ``where`` naming it in errors.

    Runs written before ``as_table`` saved every default, so their [camera] table holds keys its backend
    does not read (at their default values) and [camera.noise] beside a calibration; neither was given by
    the rig file, and both are dropped so that those runs still analyse and resume.
    """
    table = dict(data)
    cam = table.get("camera")
    if isinstance(cam, dict):
        cam = dict(cam)
        schema = CameraTable.model_fields
        defaults = CameraTable().model_dump(mode="json")
        backend = cam.get("backend", schema["backend"].default)
        read = camera_keys(backend) if isinstance(backend, str) else None
        if read is not None:
            for key in [k for k in cam if k in defaults and k not in read and cam[k] == defaults[k]]:
                del cam[key]
        if cam.get("calibration") is not None and cam.get("noise") == defaults["noise"]:
            del cam["noise"]
        table["camera"] = cam
    return parse(table, RigFile, where)


def default_axes(geometry: RigGeometry, first_id: int = 1) -> tuple[Axis, ...]:
    """One XM430-W350 per joint of the layout, ids from ``first_id``, joint 0 at mid-travel, rig limits."""
    axes = []
    for i, name in enumerate(geometry.joint_names):
        lo, hi = geometry.limits.of(name)
        axes.append(Axis(name=name, address=first_id + i, units_per_degree=X_SERIES.ticks_per_degree,
                         zero_offset_deg=-180.0, min_deg=lo, max_deg=hi, tolerance_deg=0.2))  # fmt: skip
    return tuple(axes)


#: The homing pull-off ($27) of the default GRBL axes, motor degrees: a homed axis stands this far off its switch.
GRBL_PULLOFF_DEG = 1.0
#: Steps per motor degree of the default GRBL axes: a 200-step motor at 16 microsteps, 3200 steps a turn.
GRBL_STEPS_PER_DEGREE = 3200 / 360


def grbl_homing(name: str, lo: float, hi: float, gear_ratio: float = 1.0) -> tuple[Literal[1, -1], float]:
    """(direction, zero_offset_deg) that put joint ``name``'s homing switch (GRBL's machine 0) at one end of [lo, hi].

    The camera arm homes to its lower limit, every other joint to its upper one, so homing moves the light and
    camera arms apart (a plan keeps the light above the camera). The switch is one pull-off beyond the
    limit, so a homed joint stands at the limit and every pose maps into GRBL's machine space [-$130, 0].
    """
    beyond = GRBL_PULLOFF_DEG / gear_ratio
    return (-1, lo - beyond) if name == "camera" else (1, hi + beyond)


def default_grbl_axes(geometry: RigGeometry) -> tuple[Axis, ...]:
    """One stepper per joint on GRBL axes X, Y, Z, A (in joint order), direct drive, homing as ``grbl_homing``.

    Where homing would bring the arms round the back within ``min_separation_deg`` of each other (arm limits
    of +-180 deg), the light's upper and the camera's lower limit are pulled in until it cannot.
    """
    limits = {name: geometry.limits.of(name) for name in geometry.joint_names}
    if "camera" in limits:
        (l_lo, l_hi), (c_lo, c_hi) = limits["light"], limits["camera"]
        excess = (l_hi - c_lo) - (360.0 - geometry.min_separation_deg - 2.0)
        if excess > 0:
            limits["light"], limits["camera"] = (l_lo, l_hi - excess / 2), (c_lo + excess / 2, c_hi)
    axes = []
    for letter, name in zip("XYZABC", geometry.joint_names, strict=False):
        lo, hi = limits[name]
        direction, zero = grbl_homing(name, lo, hi)
        axes.append(Axis(name=name, address=letter, units_per_degree=GRBL_STEPS_PER_DEGREE, direction=direction,
                         zero_offset_deg=zero, min_deg=lo, max_deg=hi, tolerance_deg=0.2))  # fmt: skip
    return tuple(axes)


@dataclass(frozen=True)
class RigConfig:
    """A validated rig file: the parsed tables, the geometry and the axes built from them."""

    path: Path
    file: RigFile
    geometry: RigGeometry
    axes: tuple[Axis, ...]
    #: The geometry calibration in force (``[geometry] calibration``), None for the rig as drawn.
    calibration: GeometryCalibration | None = None
    #: The sample's surface (``[sample]``): flat unless the rig file says otherwise.
    sample_shape: SampleShape = dataclasses.field(default_factory=SampleShape)

    @property
    def alignment(self) -> Alignment:
        """The rig's known imperfections: the calibration's, or none."""
        return self.calibration.alignment if self.calibration is not None else Alignment()

    def calibration_warnings(self) -> list[str]:
        """What is doubtful about the calibration in force: fitted for another geometry, residuals beyond noise."""
        cal = self.calibration
        if cal is None:
            return []
        out = [f"the geometry calibration says: {w}" for w in cal.warnings]
        if cal.rig_geometry is not None:
            differ = changes(cal.rig_geometry, fitted_for(self.file))
            if differ:
                out.append(f"{self.path}'s geometry is not what its geometry calibration {cal.path} was fitted for "
                           f"({'; '.join(differ)}): calibrate it again (gonio calibrate geometry)")  # fmt: skip
        elif cal.created_utc and self.path.is_file():  # a calibration older than the record: the file's time
            made = datetime.datetime.fromisoformat(cal.created_utc)
            changed = datetime.datetime.fromtimestamp(self.path.stat().st_mtime, datetime.UTC)
            if changed > made:
                out.append(f"{self.path} changed ({changed:%Y-%m-%d %H:%M} UTC) after its geometry calibration "
                           f"{cal.path} was made ({made:%Y-%m-%d %H:%M} UTC): if the rig was rebuilt or the sample "
                           "re-seated, calibrate again (gonio calibrate geometry)")  # fmt: skip
        if cal.reduced_chi2 is not None and cal.reduced_chi2 > RESIDUAL_LIMIT:
            out.append(f"the geometry calibration {cal.path} left residuals {cal.reduced_chi2:.2f}x its noise "
                       f"(chi2/dof above {RESIDUAL_LIMIT:g}): the rig's model does not explain its captures; "
                       "check the board and calibrate again")  # fmt: skip
        return out


@dataclass(frozen=True)
class SweepConfig:
    """A validated sweep file: the parsed tables and the BRDF directions (N, 4) in degrees it asks for."""

    path: Path
    file: SweepFile
    directions_deg: FloatArray
    discarded: int = 0


def _geometry(path: Path, cfg: RigFile) -> RigGeometry:
    g = cfg.geometry
    try:
        limits = JointLimits(**{k: tuple(v) for k, v in g.limits.model_dump().items()})
        values = g.model_dump(exclude={"limits", "calibration"})
        return RigGeometry(**values, limits=limits)
    except GeometryError as exc:
        raise ConfigError(f"{path}: [geometry] {exc}") from None


def _axes(path: Path, cfg: RigFile, geometry: RigGeometry) -> tuple[Axis, ...]:
    joints = geometry.joint_names
    unknown = sorted(set(cfg.axes) - set(joints))
    if unknown:
        raise ConfigError(
            f"{path}: axes.{unknown[0]}: no such joint in layout {geometry.layout!r}; "
            f"expected one of {', '.join(joints)}{did_you_mean(unknown[0], list(joints))}"
        )
    traits = registry.load(cfg.link.kind).for_file(cfg)
    letters = traits.addressing == "letter"
    defaults = {a.name: a for a in (default_grbl_axes(geometry) if letters else default_axes(geometry))}
    out = []
    for name in joints:
        table = cfg.axes.get(name)
        if table is None:
            if not traits.default_axes:
                raise ConfigError(f"{path}: axes.{name}: missing; a {cfg.link.kind} link needs a table for every joint")
            out.append(defaults[name])
            continue
        if letters and table.letter is None:
            raise ConfigError(f"{path}: axes.{name}.id = {table.id!r}: expected letter (a GRBL axis such as 'X')")
        if not letters and table.id is None:
            raise ConfigError(f"{path}: axes.{name}.letter = {table.letter!r}: expected id (a Dynamixel id 0..252)")
        lo, hi = geometry.limits.of(name)
        upd = table.units_per_degree
        direction = table.direction if table.direction is not None else 1
        zero = table.zero_offset_deg if table.zero_offset_deg is not None else -180.0
        simulated = letters and traits.default_axes  # a simulated controller: what a table leaves out is the default's
        if simulated:
            d = defaults[name]
            lo, hi, upd = d.min_deg, d.max_deg, (d.units_per_degree if upd is None else upd)
        lo = lo if table.min_deg is None else table.min_deg
        hi = hi if table.max_deg is None else table.max_deg
        if simulated and table.direction is None and table.zero_offset_deg is None:
            direction, zero = grbl_homing(name, lo, hi, table.gear_ratio)
        if upd is None:
            if letters:
                raise ConfigError(
                    f"{path}: axes.{name}.units_per_degree: missing; a GRBL axis needs its steps per degree"
                )
            upd = X_SERIES.ticks_per_degree
        if not letters and abs(upd - X_SERIES.ticks_per_degree) <= 1e-9 * X_SERIES.ticks_per_degree:
            _check_servo_profile(path, name, table)
        try:
            out.append(Axis(
                name=name, address=table.id if table.id is not None else str(table.letter), units_per_degree=upd,
                gear_ratio=table.gear_ratio, direction=direction, zero_offset_deg=zero,
                min_deg=lo, max_deg=hi,
                max_speed_deg_s=table.max_speed_deg_s, max_accel_deg_s2=table.max_accel_deg_s2,
                tolerance_deg=table.tolerance_deg,
            ))  # fmt: skip
        except ValueError as exc:
            raise ConfigError(f"{path}: axes.{name}: {exc}") from None
    # Each joint's known play: its own table's, else the link's default for all.
    plays = {n: t.backlash_deg for n, t in cfg.axes.items() if t.backlash_deg is not None}
    out = [dataclasses.replace(a, backlash_deg=plays.get(a.name, cfg.link.backlash_deg)) for a in out]
    ids = [a.address for a in out]
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise ConfigError(f"{path}: axes: address {dup!r} is used by two joints; expected one servo per joint")
    return tuple(out)


def _check_servo_profile(path: Path, name: str, table: AxisTable) -> None:
    """Refuse a speed or acceleration the XM430-W350 cannot take (the servo answers a Data Limit Error mid-run).

    The servo is profiled in motor terms: the joint's value times ``gear_ratio``, as the link writes it.
    """
    g = table.gear_ratio
    geared = f" (x gear_ratio {g:g} = {{motor:g}} at the servo)" if g != 1 else ""
    checks = (
        ("max_speed_deg_s", table.max_speed_deg_s, X_SERIES.velocity_units, X_SERIES.velocity_limit_units,
         X_SERIES.max_speed_deg_s, "deg/s", "its Velocity Limit, 200 x 0.229 rev/min"),
        ("max_accel_deg_s2", table.max_accel_deg_s2, X_SERIES.accel_units, X_SERIES.accel_limit_units,
         X_SERIES.max_accel_deg_s2, "deg/s^2", "its Profile Acceleration register's largest value, 32767 x 214.577 "
         "rev/min^2"),
    )  # fmt: skip
    for key, value, units, limit_units, limit, unit, why in checks:
        if limit_units is not None and units(value * g) > limit_units:
            raise ConfigError(
                f"{path}: axes.{name}.{key} = {value:g}{geared.format(motor=value * g)}: an XM430-W350 takes at "
                f"most {limit:g} {unit} ({why}); expected at most {limit / g:g} {unit} for this joint"
            )


def load_rig(path: str | Path) -> RigConfig:
    """Load and validate a rig file (TOML); raises ConfigError naming the file, key, value and expectation."""
    p = Path(path)
    cfg = _load(p, RigFile)
    return rig_config(cfg, p)


def rig_config(
    cfg: RigFile, path: str | Path = "<default rig>", *, calibration: GeometryCalibration | None = None
) -> RigConfig:
    """A RigConfig from an already validated rig table (e.g. the built-in simulated rig).

    ``calibration`` is used in place of reading ``[geometry] calibration`` (a run resumed from its
    manifest takes the one it started with).
    """
    p = Path(path)
    geometry = _geometry(p, cfg)
    axes = _axes(p, cfg, geometry)
    cam = cfg.camera
    if cam.roi is not None:
        x0, y0, x1, y1 = cam.roi
        # A real camera's frame size is known only once it delivers a frame; the simulated one renders `resolution`.
        w, h = cam.resolution if cam.backend == "simulated" else (2**31, 2**31)
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            where = f" inside {w}x{h} pixels" if cam.backend == "simulated" else " with x0 < x1 and y0 < y1"
            raise ConfigError(f"{p}: camera.roi = {list(cam.roi)!r}: expected a box (x0, y0, x1, y1){where}")
    traits = registry.load(cfg.link.kind).for_file(cfg)
    if traits.cameras and cam.backend not in traits.cameras:
        raise ConfigError(f"{p}: camera.backend = {cam.backend!r}: a {cfg.link.kind} link needs the "
                          f"{registry.listing(traits.cameras)} camera")  # fmt: skip
    if cfg.reference.kind not in ("manual", "none", *traits.references):
        raise ConfigError(f"{p}: reference.kind = {cfg.reference.kind!r}: only a rig whose backend provides it has "
                          f"a {cfg.reference.kind} reference")  # fmt: skip
    if "material" in cfg.simulation.model_fields_set:
        _material(cfg, p)  # here, not when the simulator opens: a bad parameter must stop a run before it starts
    if calibration is None and cfg.geometry.calibration is not None:
        named = Path(cfg.geometry.calibration)
        try:
            calibration = read_geometry_calibration(named if named.is_absolute() else p.parent / named)
        except CalibrationFileError as exc:
            raise ConfigError(f"{p}: geometry.calibration = {cfg.geometry.calibration!r}: {exc}") from None
    return RigConfig(p, cfg, geometry, axes, calibration, _sample_shape(p, cfg, geometry))


def _sample_shape(path: Path, cfg: RigFile, geometry: RigGeometry) -> SampleShape:
    """The ``[sample]`` table's shape in metres, refused where a curved sample would reach the arms."""
    table = cfg.sample
    if table.shape == "flat" or table.radius_mm is None:
        return SampleShape()
    r = table.radius_mm * 1e-3
    # The point of the shape farthest from the arms' axis: the sphere's bottom, the cylinder's bottom edge.
    half = 0.5 * geometry.sample_height_m if table.shape == "cylinder" else 0.0
    reach = float(np.hypot(2.0 * r, half))
    arm = min(geometry.light_radius_m, geometry.camera_radius_m)
    if reach >= arm:
        largest = 0.5 * np.sqrt(arm * arm - half * half) * 1e3
        raise ConfigError(f"{path}: sample.radius_mm = {table.radius_mm:g}: a {table.shape} of that radius reaches "
                          f"{reach:.4g} m from the arms' axis, where the arms are ({arm:g} m); expected less than "
                          f"{largest:.4g} mm")  # fmt: skip
    return SampleShape(table.shape, r)


def _directions(path: Path, cfg: SweepFile) -> tuple[FloatArray, int]:
    from rig.run.config import sweeps  # the sweep generators are only needed once a sweep file is loaded

    s = cfg.sweep
    try:
        if s.kind == "grid":
            assert s.theta_i_deg is not None and s.theta_o_deg is not None
            d = sweeps.grid(s.theta_i_deg, s.theta_o_deg, s.phi_o_deg or (180.0,), s.phi_i_deg or (0.0,))
            discarded = 0
        elif s.kind == "in_plane":
            assert s.theta_i_deg is not None and s.theta_o_deg is not None
            d = sweeps.in_plane(s.theta_i_deg, s.theta_o_deg)
            discarded = 0
        elif s.kind == "rusinkiewicz":
            assert s.theta_h_deg is not None and s.theta_d_deg is not None and s.phi_d_deg is not None
            hd = sweeps.rusinkiewicz_sweep(s.theta_h_deg, s.theta_d_deg, s.phi_d_deg, s.phi_h_deg or (0.0,))
            d, discarded = hd.points, hd.below_horizon_count
        else:
            assert s.points is not None
            d = sweeps.explicit(s.points)
            discarded = 0
    except ValueError as exc:
        raise ConfigError(f"{path}: sweep: {exc}") from None
    if s.isotropic:
        d = sweeps.isotropic(d)
    if len(d) == 0:
        raise ConfigError(f"{path}: sweep: the {s.kind!r} sweep has no points above the horizon")
    return d, discarded


def load_sweep(path: str | Path) -> SweepConfig:
    """Load and validate a sweep file (TOML) and generate its directions; ConfigError on any mistake."""
    p = Path(path)
    cfg = _load(p, SweepFile)
    return sweep_config(cfg, p)


def sweep_config(cfg: SweepFile, path: str | Path = "<sweep>") -> SweepConfig:
    """A SweepConfig from an already validated sweep table."""
    p = Path(path)
    cap = cfg.capture
    if cap.exposures_s is not None and len(cap.exposures_s) == 0:
        raise ConfigError(f"{p}: capture.exposures_s = []: expected at least one exposure in seconds, or no key")
    d, discarded = _directions(p, cfg)
    return SweepConfig(p, cfg, d, discarded)


def material_from(rig: RigConfig) -> Model:
    """The sample's model from ``[simulation.material]``: a model class of the model module and its parameters."""
    return _material(rig.file, rig.path)


def _material(cfg: RigFile, path: Path) -> Model:
    table = cfg.simulation.material
    cls = getattr(model, table.model, None)
    if not (isinstance(cls, type) and issubclass(cls, Model)) or cls is Model:
        names = sorted(n for n in dir(model) if isinstance(getattr(model, n), type)
                       and issubclass(getattr(model, n), Model) and getattr(model, n) is not Model)  # fmt: skip
        raise ConfigError(
            f"{path}: simulation.material.model = {table.model!r}: expected one of {', '.join(names)}"
            f"{did_you_mean(table.model, names)}"
        )
    given = table.parameters()
    accepted = _parameters(cls)
    where = f"{path}: simulation.material"
    for key, value in given.items():
        if key not in accepted:
            raise ConfigError(
                f"{where}.{key} = {_short(json_copy(value))}: {cls.__name__} has no parameter {key!r}; its parameters "
                f"are {', '.join(accepted) or 'none'}{did_you_mean(key, list(accepted))}"
            )
    missing = [k for k, required in accepted.items() if required and k not in given]
    if missing:
        raise ConfigError(f"{where}: {cls.__name__} needs {', '.join(missing)}; its parameters are "
                          f"{', '.join(accepted)}")  # fmt: skip
    try:
        return cls(**given)
    except (TypeError, ValueError, ArithmeticError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _parameters(cls: type[Model]) -> dict[str, bool]:
    """A model class's keyword parameters, each with whether it is required (no default)."""
    out: dict[str, bool] = {}
    for name, p in inspect.signature(cls).parameters.items():
        if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
            out[name] = p.default is p.empty
    return out
