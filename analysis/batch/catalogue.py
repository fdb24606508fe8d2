"""The batch's catalogue: ``OUT/catalogue.parquet``, one row per input, for any tool that reads Parquet.

A row holds the input and whether it was analysed (``status`` done, failed with its ``error``, or pending if
the batch stopped before it), the chosen model with its parameters and standard errors (maps from parameter
name to value) and its JSON form, the goodness of fit, the run's metadata, the paths of its outputs (relative
to the catalogue's directory, so a batch directory can be moved or shared whole) and what the task cost.
Every column's unit and meaning are in the file's metadata (rig.run.tables.parquet), and the batch's settings
under ``gonio.batch``. The schema is fixed, so a catalogue whose inputs all failed still reads with its types.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from analysis.batch.inputs import AnalyzeSettings, BatchInput
from rig.run.tables.parquet import Column, write_parquet

CATALOGUE = "catalogue.parquet"
CATALOGUE_FORMAT = "gonio-catalogue/1"
_SOURCE_FIELDS = {
    "state": ("str", "", "run state (finished, stopped, running) or 'file' for a MERL table"),
    "stop_reason": ("str", "", "why a stopped run stopped"),
    "measured": ("int", "", "points measured (runs) or random bins drawn (MERL)"),
    "planned": ("int", "", "reachable points the run's plan held"),
    "unreachable": ("int", "", "points of the sweep the rig cannot reach (not planned)"),
    "lower_bound": ("int", "", "saturated points, fitted as lower bounds"),
    "sweep_kind": ("str", "", "the sweep file's kind (grid, in_plane, list, ...)"),
    "rig_name": ("str", "", "the rig file's name"),
    "sweep_name": ("str", "", "the sweep file's name"),
    "material": ("str", "", "the simulated rig's true material, for a simulated run"),
}
#: Output columns: the column, the output's kind in the task record (analysis.exports.write.FILES), what it is.
_OUTPUTS = {
    "report": ("report", "the report page (index.html)"), "fit_json": ("fit_json", "fit.json: every number of it"),
    "material_json": ("material", "the chosen model as gonio JSON"),
    "mitsuba_xml": ("mitsuba_xml", "Mitsuba 3 BSDF, XML fragment"),
    "mitsuba_json": ("mitsuba_json", "Mitsuba 3 BSDF, scene dictionary (native plugins only)"),
    "gltf": ("gltf", "glTF 2.0 metal-roughness material"), "merl": ("merl", "MERL .binary table (with --merl)"),
}  # fmt: skip
COLUMNS: dict[str, tuple[str, str, str]] = {
    "key": ("str", "", "the input's name in the batch: its output directory"),
    "source": ("str", "", "the input as given: a run directory or a MERL .binary file"),
    "kind": ("str", "", "run, merl, or missing (no such path)"),
    "status": ("str", "", "done, failed (see error) or pending (the batch stopped before it)"),
    "error": ("str", "", "why the input failed: the error's type and message, naming the file"),
    "chosen": ("str", "", "the chosen candidate of the model ladder"),
    "model_class": ("str", "", "the chosen model's gonio class"),
    "model_json": ("str", "", "the chosen model as gonio JSON (model.serialize; from_json_dict rebuilds it)"),
    "params": ("map", "", "the chosen model's fitted parameters by name (BRDF parameters are dimensionless)"),
    "std_errors": ("map", "", "standard error of each parameter (Jacobian; null where unconstrained)"),
    "chi2": ("float", "", "weighted sum of squared residuals of the chosen fit"),
    "dof": ("int", "", "degrees of freedom: samples times channels minus parameters"),
    "reduced_chi2": ("float", "", "chi2 / dof: about 1 when the model reaches the noise"),
    "p_value": ("float", "", "probability of a chi2 this large from noise alone"),
    "aic": ("float", "", "Akaike information criterion of the chosen fit"),
    "bic": ("float", "", "Bayesian information criterion of the chosen fit"),
    "noise_reached": ("bool", "", "whether the residuals are at the noise"),
    "n_samples": ("int", "", "samples fitted"),
    "criterion": ("str", "", "criterion the ladder was chosen by (bic)"),
    "reason": ("str", "", "why this model was chosen, in words"),
    "n_warnings": ("int", "", "warnings raised while loading and fitting (listed in fit.json)"),
    **_SOURCE_FIELDS,
    "created_utc": ("str", "", "when the run was created (ISO 8601, UTC)"),
    "run_gonio_version": ("str", "", "the gonio version that recorded the run"),
    "out_dir": ("str", "", "the input's output directory, relative to the catalogue"),
    **{k: ("str", "", f"{what}, relative to the catalogue") for k, (_, what) in _OUTPUTS.items()},
    "samples_parquet": ("str", "", "the run's samples table as Parquet (beside its samples.csv), as given"),
    "wall_s": ("float", "s", "wall-clock time of the task on its worker"),
    "cpu_s": ("float", "s", "CPU time of the worker process during the task (all its threads)"),
    "fit_s": ("float", "s", "wall-clock time of fitting the ladder"),
    "worker": ("str", "", "host:pid of the worker that ran the task"),
    "finished_utc": ("str", "", "when the task ended (ISO 8601, UTC)"),
    "fingerprint": ("str", "", "digest of the input's files (size, mtime), the settings and gonio's version"),
}


def _describe(name: str) -> Column:
    return Column(*COLUMNS[name])


def catalogue_row(inp: BatchInput, record: Mapping[str, Any] | None) -> dict[str, Any]:
    """The catalogue's row of one input from its task record (None: not run yet, so pending)."""
    row: dict[str, Any] = {"key": inp.key, "source": inp.source, "kind": inp.kind, "status": "pending"}
    if record is None:
        return row
    res, timing = record.get("result") or {}, record.get("timing") or {}
    source, outputs = res.get("source") or {}, record.get("outputs") or {}
    row |= {"status": record.get("status"), "error": record.get("error"), "fingerprint": record.get("fingerprint"),
            "worker": record.get("worker"), "finished_utc": record.get("finished_utc"),
            **{k: timing.get(k) for k in ("wall_s", "cpu_s", "fit_s")}, **(record.get("run") or {})}  # fmt: skip
    if res:
        row |= {k: res.get(k) for k in ("chosen", "model_class", "params", "std_errors", "chi2", "dof", "reduced_chi2",
                                        "p_value", "aic", "bic", "noise_reached", "n_samples", "criterion", "reason",
                                        "n_warnings")}  # fmt: skip
        row["model_json"] = json.dumps(res.get("model"), sort_keys=True)
        row |= {k: source.get(k) for k in _SOURCE_FIELDS}
    row |= {"out_dir": outputs.get("dir"), **{k: outputs.get(kind) for k, (kind, _) in _OUTPUTS.items()},
            "samples_parquet": record.get("samples_parquet")}  # fmt: skip
    return row


def write_catalogue(
    out: Path, inputs: Sequence[BatchInput], records: Mapping[str, Mapping[str, Any] | None], settings: AnalyzeSettings
) -> Path:
    """Write OUT/catalogue.parquet atomically: one row per input in the order given."""
    rows = [catalogue_row(inp, records.get(inp.key)) for inp in inputs]
    meta = {"gonio.batch": json.dumps({"settings": settings.as_dict(), "inputs": len(inputs)})}
    return write_parquet(out / CATALOGUE, rows, list(COLUMNS), describe=_describe, table_format=CATALOGUE_FORMAT,
                         metadata=meta)  # fmt: skip
