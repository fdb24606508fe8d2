"""The state file of an adaptive sweep, ``OUT/adaptive.json``: what a resume needs, and the rounds so far.

Written before the first round and again after every round (atomically), so an adaptive sweep stopped at
any point (Ctrl-C, a fault, SIGKILL) can be resumed: the settings, the fitted model's name (``"auto"`` for
the model selection), the rig file's validated contents (with its geometry calibration, as a run's
manifest holds them) and the run's ``[metadata]`` are all here, so a resume needs neither the rig file nor
the command line. ``state`` is ``running`` until the merged table is written, then ``finished``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from acquisition.files.atomic import atomic_path
from model.errors import InputError
from rig.instrument.calibration_file import GeometryCalibration
from rig.run.config.files import RigConfig, as_table, rig_config, saved_rig

STATE = "adaptive.json"
FORMAT = "gonio-adaptive/1"


class AdaptiveStateError(InputError, ValueError):
    """An adaptive directory that cannot be resumed or read; the message names the file and what is wrong."""


def is_adaptive(path: str | Path) -> bool:
    """Whether ``path`` is an adaptive sweep's directory (it holds adaptive.json)."""
    return (Path(path) / STATE).is_file()


def new_state(rig: RigConfig, model: str, settings: Any, metadata: dict[str, Any]) -> dict[str, Any]:
    """The state of a sweep about to start: settings, model name, the rig as validated, no rounds."""
    return {
        "format": FORMAT, "state": "running", "model": model, "settings": dataclasses.asdict(settings),
        "rig": as_table(rig.file), "rig_path": str(rig.path),
        "geometry_calibration": rig.calibration.snapshot() if rig.calibration is not None else None,
        "metadata": metadata, "rounds": [],
    }  # fmt: skip


def write_state(out: Path, doc: dict[str, Any]) -> Path:
    """Write ``OUT/adaptive.json`` atomically (NaN stays NaN: a first round has no predicted error)."""
    target = out / STATE
    text = json.dumps(doc, indent=2, allow_nan=True) + "\n"
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return target


def read_state(out: str | Path) -> dict[str, Any]:
    """The state of the adaptive sweep in ``out``; AdaptiveStateError if it is not one or cannot be resumed."""
    where = Path(out) / STATE
    try:
        doc = json.loads(where.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AdaptiveStateError(f"{out}: not an adaptive sweep's directory (no {STATE})") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise AdaptiveStateError(f"{where}: cannot be read: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise AdaptiveStateError(f"{where}: format = {found!r}; expected {FORMAT!r} (a sweep written by a gonio "
                                 "without resume support cannot be resumed; its rounds are ordinary runs)")  # fmt: skip
    for key in ("state", "model", "settings", "rig", "rig_path", "rounds"):
        if key not in doc:
            raise AdaptiveStateError(f"{where}: no {key!r}; the file is damaged")
    return doc


def rig_of(doc: dict[str, Any], where: Path) -> RigConfig:
    """The rig an adaptive sweep was started with, rebuilt from its state (as a run's manifest rebuilds it)."""
    snap = doc.get("geometry_calibration")
    cal = GeometryCalibration.from_snapshot(snap) if snap else None
    return rig_config(saved_rig(doc["rig"], f"{where / STATE} rig"), doc["rig_path"], calibration=cal)
