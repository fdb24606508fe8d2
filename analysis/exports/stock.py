"""Which stock-Mitsuba form a fitted material exports as: the exact mapping, the projection or the RGL table.

A model with a native Mitsuba plugin maps exactly (:mod:`model.mitsuba.materials`). Any other has two stock
forms, each with the error Mitsuba shows when it renders it (:func:`model.mitsuba.projection.grid_error`):
the nearest diffuse + GGX roughconductor (:func:`model.mitsuba.projection.native_projection`) and the model
tabulated for the ``measured`` plugin (:mod:`model.mitsuba.tabulated`). Unless the caller says which
(``stock``), ``mitsuba_bsdf.*`` hold the projection where Mitsuba measures it within
:data:`SELF_CONTAINED_RMS` of the model, else the one with the lower relative RMS difference. The projection
is preferred there because it is self-contained: an analytic BSDF with no side file, so the scene dictionary
loads with ``mi.load_dict`` from any directory, while the table's ``filename`` is found only through
Mitsuba's file resolver (scenes in the export directory, or a prepended path). Measured on the default
tabulation grid (table against projection): Phong n = 30 1.8 % (124 %), anisotropic Ward 2.2 % (79 %),
Oren-Nayar 1.7 % (12 %): tabulated; Lambert + GGX with Schlick Fresnel 2.0 % (2.7 %): projected.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from analysis.exports.mitsuba import TABULATED_FILE
from model.base import BRDF
from model.mitsuba.projection import NativeProjection, native_projection
from model.mitsuba.tabulated import Tabulated, TabulationGrid, tabulate, tabulated_error

#: What ``export_material(stock=...)`` accepts: which form mitsuba_bsdf.* hold for a model without a native plugin.
STOCK_FORMS: tuple[str, ...] = ("auto", "tabulated", "projection")
#: Relative RMS difference (Mitsuba against the model) within which ``auto`` keeps the self-contained projection.
SELF_CONTAINED_RMS = 0.05


@dataclass(frozen=True, eq=False)
class StockForms:
    """The stock-Mitsuba forms of a model: the projection (or exact mapping), the table, and which is the default.

    ``chosen`` is "native" (an exact mapping: no table), "projection" or "tabulated"; ``table`` and
    ``table_error`` are None for native models and where the model could not be tabulated (``refusal`` says why);
    ``requested`` is what the caller asked for (one of STOCK_FORMS).
    """

    projection: NativeProjection
    table: Tabulated | None
    table_error: dict[str, Any] | None
    chosen: str
    refusal: str | None = None
    requested: str = "auto"
    #: Why ``chosen``: "native", "refused" (no table), "requested", "self-contained" (the projection within
    #: SELF_CONTAINED_RMS) or "closer" (the lower relative RMS difference).
    why: str = "native"


def stock_forms(
    model: BRDF, stock: str = "auto", tabulation: TabulationGrid | None = None, *, variant: str | None = None
) -> StockForms:
    """Every stock-Mitsuba form of ``model`` with its Mitsuba-measured error, and the default (``stock``)."""
    if stock not in STOCK_FORMS:
        raise ValueError(f"stock = {stock!r}; expected one of {', '.join(STOCK_FORMS)}")
    projection = native_projection(model, variant=variant)
    if projection.exact:
        return StockForms(projection, None, None, "native")
    try:
        table = tabulate(model, tabulation, variant=variant)
    except ValueError as exc:
        if stock == "tabulated":
            raise
        return StockForms(projection, None, None, "projection", refusal=str(exc), requested=stock, why="refused")
    error = tabulated_error(model, table, variant)
    if stock != "auto":
        chosen, why = stock, "requested"
    elif projection.error["rms_rel"] <= SELF_CONTAINED_RMS:
        chosen, why = "projection", "self-contained"
    else:
        chosen, why = ("tabulated" if error["rms_rel"] < projection.error["rms_rel"] else "projection"), "closer"
    return StockForms(projection, table, error, chosen, requested=stock, why=why)


def tabulated_facts(forms: StockForms) -> dict[str, Any]:
    """material.json's ``facts.mitsuba_tabulated``: the table's file, size, grid and Mitsuba-measured error."""
    table, error = forms.table, forms.table_error
    if table is None or error is None:
        return {"file": None, "refusal": forms.refusal}
    g = table.grid
    return {
        "file": TABULATED_FILE, "plugin": "measured", "size_bytes": table.size_bytes, "isotropic": table.isotropic,
        "symmetry": table.symmetry, "rgb_shape": list(table.fields["rgb"].shape),
        "grid": {"samples": g.samples, "theta_i": g.theta_i, "phi_i": g.phi_i, "ndf": g.ndf},
        "note": "RGL .bsdf (Dupuy & Jakob 2018) for Mitsuba's measured plugin, rgb variants; NDF from the "
                "model's retro-reflection (model.mitsuba.tabulated)",
        "error": error,
    }  # fmt: skip
