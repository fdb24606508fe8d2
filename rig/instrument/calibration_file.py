"""``geometry_calibration.json``: a rig's fitted imperfections, their uncertainties, and how they were found.

Written by ``gonio calibrate geometry`` (``rig.alignment``), applied by a rig file's
``[geometry] calibration = "path"``. One entry per fitted quantity at the top level, with the names of
``[simulation.misalignment]`` (``light_zero_deg``, ``camera_zero_deg``, ``tilt_zero_deg``,
``roll_zero_deg``, ``sample_tilt_deg``, ``sample_tilt_azimuth_deg``, ``sample_offset_mm``; ``yaw_zero_deg``
on a fixed-camera rig), each ``{"value": ..., "std_error": ...}`` (degrees, millimetres; the offset as
[x, y, z] lists). Beside them: ``covariance`` and ``correlation`` of the fit's own parameters (``names``;
the wedge as its x, y components), ``residuals`` (pixels, chi2), ``captures`` (the joints read back and what
each frame showed), ``sensor_px`` (the [width, height] in pixels of the whole frames it was fitted on: the
camera model's sensor, which image mode's tiles are checked against), ``warnings``, and ``rig`` (the rig
file's path and SHA-256 when it was calibrated, and ``geometry``: the tables it was fitted for,
``rig.run.config.fitted_for``).
"""

from __future__ import annotations

import dataclasses
import datetime
import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from model.errors import InputError
from rig.instrument.alignment import Alignment

FloatArray = npt.NDArray[np.float64]

FILE_NAME = "geometry_calibration.json"
FORMAT = "gonio geometry calibration"
VERSION = 1
#: chi2/dof of a geometry calibration above which its residuals are beyond its noise (warned of).
RESIDUAL_LIMIT = 2.0
SCALARS = ("light_zero_deg", "camera_zero_deg", "tilt_zero_deg", "roll_zero_deg", "yaw_zero_deg",
           "sample_tilt_deg", "sample_tilt_azimuth_deg")  # fmt: skip


class CalibrationFileError(InputError, ValueError):
    """A geometry calibration file is unreadable or inconsistent; the message names the file and the key."""


@dataclass(frozen=True)
class GeometryCalibration:
    """A rig's fitted imperfections: the alignment, the fit's covariance (``names``), and where it came from."""

    alignment: Alignment
    names: tuple[str, ...] = ()
    covariance: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    path: Path | None = None
    created_utc: str | None = None
    rig_sha256: str | None = None
    reduced_chi2: float | None = None
    warnings: tuple[str, ...] = ()
    #: The rig file's tables it was fitted for (``rig.run.config.fitted_for``); None in a file older than the record.
    rig_geometry: dict[str, Any] | None = None
    #: The (width, height) in pixels of the whole frames it was fitted on; None in a file older than the record.
    sensor_px: tuple[int, int] | None = None

    def snapshot(self) -> dict[str, Any]:
        """JSON-ready form for a run's manifest, so a resumed run corrects exactly as it started."""
        return {"alignment": dataclasses.asdict(self.alignment), "names": list(self.names),
                "covariance": self.covariance.tolist(), "path": str(self.path) if self.path else None,
                "created_utc": self.created_utc, "rig_sha256": self.rig_sha256, "reduced_chi2": self.reduced_chi2,
                "warnings": list(self.warnings),
                "sensor_px": list(self.sensor_px) if self.sensor_px else None}  # fmt: skip

    @classmethod
    def from_snapshot(cls, doc: dict[str, Any]) -> GeometryCalibration:
        """The calibration a manifest's snapshot holds."""
        a = dict(doc["alignment"])
        a["sample_offset_mm"] = tuple(a["sample_offset_mm"])
        return cls(Alignment(**a), tuple(doc.get("names", ())), np.asarray(doc.get("covariance", []), dtype=float)
                   .reshape(len(doc.get("names", ())), len(doc.get("names", ()))),
                   Path(doc["path"]) if doc.get("path") else None, doc.get("created_utc"), doc.get("rig_sha256"),
                   doc.get("reduced_chi2"), tuple(doc.get("warnings", ())),
                   sensor_px=_sensor(doc.get("sensor_px")))  # fmt: skip

    def describe(self) -> str:
        """One line for ``gonio plan``: where the calibration is from, when, and its largest corrections."""
        a = self.alignment
        zeros = ", ".join(f"{n.removesuffix('_zero_deg')} {getattr(a, n):+.3f}" for n in SCALARS[:4])
        where = f"{self.path}" if self.path else "(in memory)"
        when = f" of {self.created_utc}" if self.created_utc else ""
        return (f"geometry calibration {where}{when}: zeros (deg) {zeros}; sample tilt {a.sample_tilt_deg:.3f} deg "
                f"towards {a.sample_tilt_azimuth_deg:.1f} deg; offset (mm) "
                f"{', '.join(f'{v:+.2f}' for v in a.sample_offset_mm)}")  # fmt: skip


def sha256_of(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, hex."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _number(path: Path, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CalibrationFileError(f"{path}: {key} = {value!r}: expected a finite number")
    return float(value)


def _sensor(value: Any) -> tuple[int, int] | None:
    """A (width, height) pair of positive whole pixels, None if absent; ValueError otherwise."""
    if value is None:
        return None
    if (not isinstance(value, list | tuple) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in value)):  # fmt: skip
        raise ValueError(f"{value!r}: expected [width, height] in whole pixels")
    return int(value[0]), int(value[1])


def read_geometry_calibration(path: str | Path) -> GeometryCalibration:
    """Read ``geometry_calibration.json``; CalibrationFileError names the file, the key and what was expected."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CalibrationFileError(f"{p}: no such file (run `gonio calibrate geometry` to make one)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CalibrationFileError(f"{p}: not a readable JSON file: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise CalibrationFileError(f"{p}: format = {doc.get('format') if isinstance(doc, dict) else doc!r}: "
                                   f"expected {FORMAT!r}")  # fmt: skip
    if doc.get("version") != VERSION:
        raise CalibrationFileError(f"{p}: version = {doc.get('version')!r}: this gonio reads version {VERSION}")
    values: dict[str, Any] = {}
    for name in SCALARS:
        entry = doc.get(name)
        if entry is None:
            continue
        if not isinstance(entry, dict) or "value" not in entry:
            raise CalibrationFileError(f"{p}: {name} = {entry!r}: expected {{\"value\": ..., \"std_error\": ...}}")
        values[name] = _number(p, f"{name}.value", entry["value"])
    offset = doc.get("sample_offset_mm", {"value": [0.0, 0.0, 0.0]})
    vec = offset.get("value") if isinstance(offset, dict) else None
    if not isinstance(vec, list) or len(vec) != 3:
        raise CalibrationFileError(f"{p}: sample_offset_mm.value = {vec!r}: expected [x, y, z] in mm")
    values["sample_offset_mm"] = tuple(_number(p, f"sample_offset_mm.value[{i}]", v) for i, v in enumerate(vec))
    try:
        alignment = Alignment(**values)
    except ValueError as exc:
        raise CalibrationFileError(f"{p}: {exc}") from None
    cov = doc.get("covariance", {})
    names = tuple(cov.get("names", ())) if isinstance(cov, dict) else ()
    matrix = np.asarray(cov.get("matrix", np.zeros((0, 0))) if isinstance(cov, dict) else np.zeros((0, 0)), dtype=float)
    if matrix.shape != (len(names), len(names)) or not np.all(np.isfinite(matrix)):
        raise CalibrationFileError(f"{p}: covariance.matrix: expected a finite {len(names)} x {len(names)} matrix "
                                   f"for covariance.names, got shape {matrix.shape}")  # fmt: skip
    try:
        sensor = _sensor(doc.get("sensor_px"))
    except ValueError as exc:
        raise CalibrationFileError(f"{p}: sensor_px = {exc}") from None
    rig = doc.get("rig", {}) if isinstance(doc.get("rig"), dict) else {}
    residuals = doc.get("residuals", {}) if isinstance(doc.get("residuals"), dict) else {}
    return GeometryCalibration(
        alignment, names, matrix, p, doc.get("created_utc"), rig.get("sha256"), residuals.get("reduced_chi2"),
        tuple(str(w) for w in doc.get("warnings", [])),
        rig["geometry"] if isinstance(rig.get("geometry"), dict) else None, sensor,
    )  # fmt: skip


def write_geometry_calibration(path: str | Path, doc: dict[str, Any]) -> Path:
    """Write a calibration document (its entries as ``rig.alignment`` builds them) atomically; returns the path."""
    from acquisition.files.atomic import write_atomic

    full = {"format": FORMAT, "version": VERSION,
            "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), **doc}  # fmt: skip
    text = json.dumps(full, indent=2, allow_nan=False) + "\n"
    return write_atomic(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))
