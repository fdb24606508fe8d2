"""Every error class of gonio has a kind (model/errors.py), and the command line maps an error by its kind alone.

The kinds replaced lists of classes in gonio/cli_errors.py; ``BEFORE`` keeps what those lists said, so that each
class's exit code is pinned to the one it had, and a new class without a kind fails here by name.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

from gonio import cli
from model.errors import CameraFault, GonioError, HardwareFault, InputError

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("model", "acquisition", "rig", "simulator", "analysis", "gonio")

#: The classes gonio/cli_errors.py listed before the kinds, by exit code (their subclasses went with them).
BEFORE = {
    3: ("rig.instrument.links.base.LinkError",),
    4: ("acquisition.cameras.CameraError", "rig.run.backends.bounded_camera.CameraError"),
    2: ("gonio.cli_errors.CliError", "rig.run.config.files.ConfigError", "rig.run.storage.store.RunStoreError",
        "analysis.result.AnalysisError", "rig.instrument.axis.AxisLimitError", "rig.instrument.geometry.GeometryError",
        "rig.instrument.kinematics_types.UnreachableError", "model._params.ParameterError",
        "model.serialize.ModelFormatError", "model.merl.MerlFormatError", "model.fit.samples.FitError",
        "acquisition.flatfield.FlatFieldError", "acquisition.calibration.CalibrationError",
        "rig.run.registry.BackendError", "acquisition.cameras.BackendNotInstalledError",
        "rig.run.adaptive.state.AdaptiveStateError", "rig.run.backends.reference.OperatorAbsent"),
}  # fmt: skip
#: Classes that were in no list (a bug, exit 70, had they reached the command line) and now have a kind: each is
#: handled before it could, by its command or inside the run, with the code its kind now carries.
GIVEN_A_KIND = {
    "acquisition.board.BoardError": "gonio calibrate geometry catches it: exit 2",
    "rig.alignment.fit.CalibrationError": "gonio calibrate geometry catches it: exit 2",
    "rig.alignment.poses.PoseError": "gonio calibrate geometry catches it: exit 2",
    "acquisition.photon_transfer.PhotonTransferError": "gonio calibrate camera catches it: exit 4",
    "rig.run.measuring.runner._CameraFailed": "never leaves the runner, which stops the run on it (exit 4)",
    "simulator.rehearsal.RehearsalError": "a rig file gonio sim rig cannot rehearse is bad input: now exit 2, was 70",
    "rig.instrument.calibration_file.CalibrationFileError": "a bad calibration file is bad input: now exit 2, was 70",
    "rig.instrument.links.dynamixel_table.UnknownModelError": "a servo of unknown model is hardware: now 3, was 70",
    "rig.run.measuring.image_capture.ImageModeError": "new: a rig file's sensor size or a sweep's tile_px: exit 2",
}


def _name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _error_classes() -> list[type[BaseException]]:
    """Every exception class defined at the top of a module of gonio's packages but the kinds' (warnings: no)."""
    found: dict[str, type[BaseException]] = {}
    for package in PACKAGES:
        top = importlib.import_module(package)
        for module in [package, *(m.name for m in pkgutil.walk_packages(top.__path__, package + "."))]:
            for obj in vars(importlib.import_module(module)).values():
                if (isinstance(obj, type) and issubclass(obj, BaseException) and not issubclass(obj, Warning)
                        and obj.__module__ == module and module != "model.errors"):  # fmt: skip
                    found[_name(obj)] = obj
    return [found[k] for k in sorted(found)]


ERRORS = _error_classes()


def _code_before(cls: type[BaseException]) -> int:
    for code, names in BEFORE.items():
        if any(_name(base) in names for base in cls.__mro__):
            return code
    return GonioError.exit_code


def test_the_walk_finds_the_errors() -> None:
    names = {_name(cls) for cls in ERRORS}
    assert {n for listed in BEFORE.values() for n in listed} <= names
    assert set(GIVEN_A_KIND) <= names and "simulator.grbl.gcode.GcodeError" in names


@pytest.mark.parametrize("cls", ERRORS, ids=_name)
def test_every_error_class_has_a_kind_and_keeps_its_exit_code(cls: type[BaseException]) -> None:
    assert issubclass(cls, GonioError), f"{_name(cls)} derives from no kind of model/errors.py"
    if _name(cls) == "rig.run.measuring.runner.RunStopped":
        return  # its code is its cause's: below
    expected = _code_before(cls)
    if _name(cls) in GIVEN_A_KIND:
        assert expected == GonioError.exit_code and cls.exit_code != expected  # type: ignore[attr-defined]
    else:
        assert cls.exit_code == expected  # type: ignore[attr-defined]


def test_a_kind_adds_no_builtin_base() -> None:
    # An `except ValueError` must catch what it caught before: the kinds bring nothing but GonioError.
    for kind in (GonioError, InputError, HardwareFault, CameraFault):
        assert set(kind.__mro__) <= {kind, InputError, HardwareFault, CameraFault, GonioError, Exception,
                                     BaseException, object}  # fmt: skip


def test_the_command_line_lists_no_error_classes() -> None:
    tree = ast.parse((REPO / "gonio" / "cli_errors.py").read_text())
    listed = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES:
            for alias in node.names:
                found = getattr(importlib.import_module(node.module), alias.name)
                is_error = isinstance(found, type) and issubclass(found, BaseException)
                if is_error and node.module != "model.errors":
                    listed.append(f"{node.module}.{alias.name}")
    assert not listed, f"gonio/cli_errors.py imports error classes {listed}: it should map errors by kind"


class LabStageError(HardwareFault, RuntimeError):
    """A lab's own link error, from a package gonio does not know."""


def _error(module: str, name: str, *args: object) -> BaseException:
    cls: type[BaseException] = getattr(importlib.import_module(module), name)
    return cls(*args)


@pytest.mark.parametrize(("exc", "code", "line"), [
    (_error("rig.run.config.files", "ConfigError", "rig.toml: bad"), 2, "gonio: error: rig.toml: bad"),
    (_error("rig.instrument.links.dynamixel_bus", "CommunicationError", "no reply"), 3,
     "gonio: hardware fault: no reply"),
    (LabStageError("stage 2 lost"), 3, "gonio: hardware fault: stage 2 lost"),
    (_error("acquisition.cameras", "CameraError", "no frame"), 4, "gonio: camera fault: no frame"),
    (_error("rig.run.measuring.runner", "RunStopped", "runs/x: stopped on a camera fault", "camera"), 4,
     "gonio: runs/x: stopped on a camera fault"),
    (_error("rig.run.measuring.runner", "RunStopped", "runs/x: interrupted", "interrupted"), 130,
     "gonio: runs/x: interrupted"),
    (_error("acquisition.frame", "FrameError", "bad frame"), 70,
     "gonio: internal error (a bug in gonio, not in your input): FrameError: bad frame"),
])  # fmt: skip
def test_the_command_line_maps_an_error_by_its_kind(exc, code, line, monkeypatch, capsys) -> None:  # type: ignore[no-untyped-def]
    def broken(*_args: object, **_kw: object) -> None:
        raise exc

    monkeypatch.setattr("gonio.models_demo.write_slices", broken)
    assert cli.main(["models"]) == code
    assert capsys.readouterr().err.splitlines()[0] == line
