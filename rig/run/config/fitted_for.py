"""What a geometry calibration is fitted for: the rig file's tables that place the joints and the sample.

``gonio calibrate geometry`` records them (``fitted_for``) in ``geometry_calibration.json``; a rig file that
applies the calibration is compared with them (``changes``), so gonio warns when the geometry really changed
and not when the file did: pointing ``[geometry] calibration`` at the file, as the documented workflow does
after calibrating, edits the rig file but not its geometry. They are ``[geometry]`` (but its ``calibration``),
``[axes]`` (a joint's zero is relative to its axis's), the link's kind (it sets the default axes) and a
simulated rig's build (``[simulation]`` link and the geometric keys of its misalignment), each as it differs
from the defaults, so a default written out or left out is the same geometry.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel

from rig.instrument.alignment import Alignment
from rig.run.config.schema import RigFile

#: The keys of ``[simulation.misalignment]`` that are the rig's geometry (what a calibration fits), not its lamp.
GEOMETRIC = frozenset(f.name for f in dataclasses.fields(Alignment))


def _set(table: BaseModel, **keys: Any) -> dict[str, Any]:
    return table.model_dump(mode="json", exclude_defaults=True, **keys)


def fitted_for(cfg: RigFile) -> dict[str, Any]:
    """The rig file's geometry as a calibration records it: JSON-ready tables of what differs from the defaults."""
    sim = cfg.simulation
    return {
        "geometry": _set(cfg.geometry, exclude={"calibration"}),
        "axes": {name: _set(axis) for name, axis in sorted(cfg.axes.items())},
        "link": _set(cfg.link, include={"kind"}),
        "simulation": {**_set(sim, include={"link"}), "misalignment": _set(sim.misalignment, include=GEOMETRIC)},
    }


def _flat(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, Mapping):
            out |= _flat(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def changes(recorded: Mapping[str, Any], now: Mapping[str, Any]) -> list[str]:
    """Each key whose value differs between two ``fitted_for`` records, ``key = now (was then)``; [] if none."""
    a, b = _flat(recorded), _flat(now)
    return [f"{key} = {b.get(key, 'default')} (was {a.get(key, 'default')})"
            for key in sorted(set(a) | set(b)) if a.get(key) != b.get(key)]  # fmt: skip
