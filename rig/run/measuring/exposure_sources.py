"""What predicts a point's light level before it is measured: a fitted model or an earlier pass.

``[capture] exposure_model`` names a model file that ``gonio analyze`` writes: ``fit.json`` (its ``"model"`` is the
chosen model) or ``export/material.json`` (the model itself, with facts). That is what a user holds after a first
pass, and both read back exactly through ``model.serialize``; a rig file's ``[simulation.material]`` is the
simulator's truth, which a real rig never has. The model's signal at a direction pair is f_r(wi, wo) cos(theta_i):
the radiance under a unit lamp at unit distance, in the model's own units. Only its shape matters: the planner
(``rig.run.measuring.exposure_ahead``) calibrates its scale from the run's own readings.

``[capture] exposure_from`` names an earlier run: its directory (its journal's point records, readable while that
run stands stopped, with each point's level) or a ``samples.csv`` (the readings alone). The signal at a direction
pair is the reading (counts/s, per channel, exposure already divided out) of the nearest measured pair, within
``PASS_REACH_DEG``; a run on the same rig predicts in the camera's own units, so it plans even the first point.

Paths are relative to the sweep file. A path that does not exist, a file that cannot be read, or one of another
format is a ConfigError naming the sweep file, the key, the path and what was expected, raised before anything
moves. Both sources only plan exposures: no reading's value or error depends on them.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from model.base import Model
from model.geometry import degrees_to_vector
from model.serialize import from_json_dict
from rig.run.config.files import ConfigError
from rig.run.storage.store import RunStore, RunStoreError

#: Farthest (deg, in either direction of the pair) an earlier pass's measured pair may lie and still predict.
PASS_REACH_DEG = 10.0
#: The table columns a pass's samples.csv must have (angles in degrees, readings in counts/s).
ANGLES = ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")
READINGS = ("reading_r", "reading_g", "reading_b")

Signal = npt.NDArray[np.float64]


class LevelSource(Protocol):
    """Predicts a point's light level per channel (its own units) from its BRDF directions (deg)."""

    @property
    def name(self) -> str:
        """What the journal calls it ("model" or "pass")."""
        ...

    @property
    def prior_scale(self) -> float | None:
        """The scale from its units to counts/s before the run's own readings calibrate it (None: unknown)."""
        ...

    def signal(self, directions_deg: tuple[float, float, float, float]) -> Signal | None:
        """The predicted level per channel at (theta_i, phi_i, theta_o, phi_o) in degrees; None: no prediction."""
        ...

    def template(self, directions_deg: tuple[float, float, float, float]) -> dict[str, Any] | None:
        """A level (the journal's ``level`` object) whose shape (peak, dark, pixels) a prediction may borrow."""
        ...


def _positive(values: npt.ArrayLike) -> Signal | None:
    a = np.atleast_1d(np.asarray(values, dtype=np.float64)).reshape(-1)
    return a if a.size and bool(np.all(np.isfinite(a))) and bool(np.all(a > 0)) else None


@dataclass(frozen=True)
class ModelSource:
    """A fitted model: f_r cos(theta_i) under a unit lamp (``path`` says where it came from)."""

    model: Model
    path: str
    name: str = "model"
    prior_scale: float | None = None

    def signal(self, directions_deg: tuple[float, float, float, float]) -> Signal | None:
        """f_r(wi, wo) cos(theta_i) in 1/sr per channel; None where the model gives no light (beyond the horizon)."""
        ti, pi, to, po = (float(v) for v in directions_deg)
        if not (abs(ti) < 90.0 and abs(to) < 90.0):
            return None
        wi, wo = degrees_to_vector(ti, pi), degrees_to_vector(to, po)
        f = np.asarray(self.model.eval(wi, wo), dtype=np.float64)
        return _positive(f * math.cos(math.radians(ti)))

    def template(self, directions_deg: tuple[float, float, float, float]) -> dict[str, Any] | None:
        """None: a model knows no pixel statistics."""
        return None


@dataclass(frozen=True)
class PassSource:
    """An earlier run's readings (counts/s) at its measured directions; levels where its journal kept them."""

    wi: npt.NDArray[np.float64]  # (N, 3) unit vectors
    wo: npt.NDArray[np.float64]
    readings: tuple[tuple[float, ...], ...]
    levels: tuple[dict[str, Any] | None, ...]
    path: str
    name: str = "pass"
    prior_scale: float | None = 1.0

    def _nearest(self, directions_deg: tuple[float, float, float, float]) -> int | None:
        ti, pi, to, po = (float(v) for v in directions_deg)
        wi, wo = degrees_to_vector(ti, pi), degrees_to_vector(to, po)
        ci, co = self.wi @ wi, self.wo @ wo
        k = int(np.argmax(ci + co))
        reach = math.cos(math.radians(PASS_REACH_DEG))
        return k if ci[k] >= reach and co[k] >= reach else None

    def signal(self, directions_deg: tuple[float, float, float, float]) -> Signal | None:
        """The nearest measured pair's reading (counts/s per channel); None beyond PASS_REACH_DEG or dark there."""
        k = self._nearest(directions_deg)
        return None if k is None else _positive(self.readings[k])

    def template(self, directions_deg: tuple[float, float, float, float]) -> dict[str, Any] | None:
        """The nearest measured pair's level (a run directory's journal keeps it; a samples.csv does not)."""
        k = self._nearest(directions_deg)
        return None if k is None else self.levels[k]


class _Where:
    """How an error names the value: the sweep file, the key, the path given and the path it resolved to."""

    def __init__(self, sweep_path: Path, key: str, given: str) -> None:
        self.key, self.given = key, given
        named = Path(given).expanduser()
        self.path = named if named.is_absolute() else sweep_path.parent / named
        self.head = f"{sweep_path}: capture.{key} = {given!r}"

    def error(self, what: str) -> ConfigError:
        return ConfigError(f"{self.head}: {what}")


def load_model_source(sweep_path: str | Path, given: str) -> ModelSource:
    """``[capture] exposure_model``: a fit.json or material.json of ``gonio analyze``, as a ModelSource."""
    where = _Where(Path(sweep_path), "exposure_model", given)
    expected = "expected gonio analyze's fit.json or export/material.json (a model and its parameters)"
    p = where.path
    if p.is_dir():
        raise where.error(f"{p} is a directory ({expected}, such as {p / 'analysis' / 'fit.json'}; an earlier run's "
                          "directory itself is exposure_from's)")  # fmt: skip
    if not p.is_file():
        raise where.error(f"no such file {p} ({expected})")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise where.error(f"cannot read {p}: {exc}") from None
    except ValueError as exc:
        raise where.error(f"{p} is not JSON ({exc}); {expected}") from None
    if isinstance(doc, dict) and isinstance(doc.get("model"), dict):
        doc = doc["model"]  # fit.json: the chosen model
    if not isinstance(doc, dict) or not isinstance(doc.get("model"), str):
        raise where.error(f"{p} holds no model ({expected})")
    try:
        model = from_json_dict(doc, str(p))
    except ValueError as exc:  # ModelFormatError: the class or a parameter, named
        raise where.error(f"{exc}") from None
    return ModelSource(model, str(p))


def load_pass_source(sweep_path: str | Path, given: str) -> PassSource:
    """``[capture] exposure_from``: an earlier run's directory or samples.csv, as a PassSource."""
    where = _Where(Path(sweep_path), "exposure_from", given)
    p = where.path
    if p.is_dir():
        source = _from_run(where, p)
    elif p.is_file():
        source = _from_table(where, p)
    else:
        raise where.error(f"no such run directory or file {p} (expected an earlier run's directory or samples.csv)")
    if not source.readings:
        raise where.error(f"{p} holds no measured point (expected an earlier run with at least one reading)")
    return source


def _from_run(where: _Where, path: Path) -> PassSource:
    try:
        records = RunStore.read(path).records()
    except RunStoreError as exc:
        raise where.error(f"not a readable run directory ({exc}); expected an earlier run's directory or "
                          "samples.csv") from None  # fmt: skip
    wi, wo, readings, levels = [], [], [], []
    for rec in records:
        if rec.get("kind") != "point":
            continue
        try:
            angles = [float(rec[k]) for k in ANGLES]
            reading = tuple(float(v) for v in rec["reading"])
            level = dict(rec["level"])
        except (KeyError, TypeError, ValueError) as exc:
            raise where.error(f"{path / 'journal.jsonl'}: a point record without its angles, reading or level "
                              f"({type(exc).__name__}: {exc})") from None  # fmt: skip
        wi.append(degrees_to_vector(angles[0], angles[1]))
        wo.append(degrees_to_vector(angles[2], angles[3]))
        readings.append(reading)
        levels.append(level)
    return _pass(wi, wo, readings, levels, path)


def _from_table(where: _Where, path: Path) -> PassSource:
    expected = f"expected a samples.csv with columns {', '.join(ANGLES + READINGS)}"
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise where.error(f"cannot read {path}: {exc}") from None
    columns = set(reader.fieldnames or ())
    missing = [c for c in ANGLES + READINGS if c not in columns]
    if missing:
        raise where.error(f"{path} lacks column(s) {', '.join(missing)} ({expected})")
    wi, wo, readings = [], [], []
    for line, row in enumerate(rows, 2):
        try:
            angles = [float(row[k]) for k in ANGLES]
            reading = tuple(float(row[k]) for k in READINGS)
        except (TypeError, ValueError) as exc:
            raise where.error(f"{path}, line {line}: {exc} ({expected}, numbers)") from None
        if not all(math.isfinite(v) for v in angles):
            raise where.error(f"{path}, line {line}: angles {angles} ({expected}, finite numbers)")
        wi.append(degrees_to_vector(angles[0], angles[1]))
        wo.append(degrees_to_vector(angles[2], angles[3]))
        readings.append(reading)
    return _pass(wi, wo, readings, [None] * len(readings), path)


def _pass(wi: list[Any], wo: list[Any], readings: list[tuple[float, ...]], levels: Sequence[dict[str, Any] | None],
          path: Path) -> PassSource:  # fmt: skip
    shape = (len(readings), 3)
    return PassSource(np.asarray(wi, dtype=np.float64).reshape(shape), np.asarray(wo, dtype=np.float64).reshape(shape),
                      tuple(readings), tuple(levels), str(path))  # fmt: skip


def load_sources(sweep_path: str | Path, exposure_from: str | None,
                 exposure_model: str | None) -> tuple[LevelSource, ...]:  # fmt: skip
    """The sources a sweep's [capture] names, the earlier pass first (measured beats modelled); () for none."""
    out: list[LevelSource] = []
    if exposure_from is not None:
        out.append(load_pass_source(sweep_path, exposure_from))
    if exposure_model is not None:
        out.append(load_model_source(sweep_path, exposure_model))
    return tuple(out)
