"""Models as plain JSON: ``{"model": class name, "params": {field: number, string, list or null}}``.

A fitted model has to outlive the process that fitted it: the analysis writes it next to its exports,
the Mitsuba plugin rebuilds it from a string property, and a person reads it. Every analytic model is a
frozen dataclass of numbers, strings and per-channel tuples, so its fields *are* its serialised form; a
tuple becomes a list, :class:`model.LafortuneLobe` entries become objects with their own fields.
Reading builds the model through its constructor, so the same validation applies as in code, and an
error names the source (a file name, a property), the key path and what was expected.

Which classes: the analytic models exported by :mod:`model` (registered by name in :data:`MODELS`),
matched by exact type (a subclass may change the physics its parameters mean). A :class:`model.MerlTable`
is 1.46 million numbers per channel, not parameters: it is refused with a pointer to
:func:`model.write_merl`. Fields missing from ``params`` take the class's defaults, as in the
constructor; top-level keys besides "model" and "params" are left to the caller (metadata such as an
export's facts) and ignored here.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from typing import Any

from model._params import ParameterError
from model.ashikhmin_shirley import AshikhminShirley
from model.base import BRDF, Model
from model.blinn_phong import BlinnPhong
from model.cook_torrance import CookTorrance
from model.errors import InputError
from model.kajiya_kay import KajiyaKay
from model.lafortune import Lafortune, LafortuneLobe
from model.lambert import Lambert
from model.merl import MerlTable
from model.metal_roughness import MetalRoughness
from model.metalness_mix import MetalnessMix
from model.oren_nayar import OrenNayar
from model.phong import Phong
from model.ward import Ward

#: Serialisable model classes by the name written in "model".
MODELS: dict[str, type[Model]] = {
    cls.__name__: cls
    for cls in (
        AshikhminShirley, BlinnPhong, CookTorrance, KajiyaKay, Lafortune, Lambert, MetalRoughness,
        MetalnessMix, OrenNayar, Phong, Ward,
    )
}  # fmt: skip
#: Dataclasses that may appear nested inside a model's fields (as JSON objects).
NESTED: tuple[type, ...] = (LafortuneLobe,)

_MERL_WHY = (
    "a MerlTable is a tabulated BRDF (3 x 1,458,000 numbers), not model parameters: "
    "write it with model.write_merl and read it with model.read_merl"
)


class ModelFormatError(InputError, ValueError):
    """A model's JSON form is not valid: unknown class or field, wrong type, or a value out of range."""


def _kind(hint: Any) -> str | type:
    """The JSON shape of a field from its annotation: str, number, optional, channel, or a nested class."""
    if hint is str:
        return "str"
    if hint is float:
        return "number"
    args = typing.get_args(hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        if set(args) == {float, type(None)}:
            return "optional"
        if float in args and tuple[float, ...] in args:
            return "channel"
    if typing.get_origin(hint) is tuple and len(args) == 2 and args[1] is Ellipsis and args[0] in NESTED:
        return typing.cast(type, args[0])
    raise TypeError(f"no JSON form for a field annotated {hint!r}")


def _field_kinds(cls: type) -> dict[str, str | type]:
    """Field name -> JSON shape for a dataclass (annotations resolved in its own module)."""
    hints = typing.get_type_hints(cls)
    return {f.name: _kind(hints[f.name]) for f in dataclasses.fields(cls)}


def _encode(obj: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, kind in _field_kinds(type(obj)).items():
        v = getattr(obj, name)
        if isinstance(kind, type):
            out[name] = [_encode(item) for item in v]
        elif v is None or isinstance(v, str):
            out[name] = v
        elif isinstance(v, tuple):
            out[name] = [float(x) for x in v]
        else:
            out[name] = float(v)
    return out


def to_json_dict(model: BRDF) -> dict[str, Any]:
    """The model as ``{"model": class name, "params": {field: float, list, str or None}}`` (JSON-ready)."""
    cls = type(model)
    if cls is MerlTable:
        raise TypeError(_MERL_WHY)
    if MODELS.get(cls.__name__) is not cls:
        raise TypeError(f"{cls.__name__} has no JSON form; serialisable models: {', '.join(sorted(MODELS))}")
    return {"model": cls.__name__, "params": _encode(model)}


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _decode_value(kind: str | type, v: Any, where: str) -> Any:
    """One field's JSON value as the constructor takes it; ``where`` names it in errors."""
    if isinstance(kind, type):
        if not isinstance(v, list) or not v:
            raise ModelFormatError(f"{where} = {v!r}: expected a non-empty list of {kind.__name__} objects")
        return tuple(_decode_fields(kind, item, f"{where}[{i}]") for i, item in enumerate(v))
    if kind == "str":
        if not isinstance(v, str):
            raise ModelFormatError(f"{where} = {v!r}: expected a string")
        return v
    if kind == "optional" and v is None:
        return None
    if _is_number(v):
        return float(v)
    if kind == "channel" and isinstance(v, list) and v and all(_is_number(x) for x in v):
        return tuple(float(x) for x in v)
    expected = {
        "number": "a number",
        "optional": "a number or null",
        "channel": "a number or a non-empty list of numbers (one per channel)",
    }[kind]
    raise ModelFormatError(f"{where} = {v!r}: expected {expected}")


def _decode_fields(cls: type, params: Any, where: str) -> Any:
    """Build ``cls`` from a JSON object of its fields, checking names and types first."""
    if not isinstance(params, Mapping):
        raise ModelFormatError(f"{where} = {params!r}: expected an object of {cls.__name__} fields")
    kinds = _field_kinds(cls)
    unknown = sorted(set(params) - set(kinds))
    if unknown:
        raise ModelFormatError(
            f"{where}: unknown field(s) {', '.join(map(repr, unknown))} for {cls.__name__}; "
            f"expected some of {', '.join(kinds)}"
        )
    kwargs = {name: _decode_value(kinds[name], v, f"{where}.{name}") for name, v in params.items()}
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        raise ModelFormatError(f"{where}: {exc}") from exc


def from_json_dict(d: Any, source: str = "") -> Model:
    """The model described by ``d`` (as from :func:`to_json_dict`); errors name ``source`` and the key."""
    src = source or "model JSON"
    if not isinstance(d, Mapping):
        raise ModelFormatError(f"{src}: expected an object with 'model' and 'params'; got {type(d).__name__}")
    for key in ("model", "params"):
        if key not in d:
            raise ModelFormatError(f"{src}: missing key {key!r} (keys present: {', '.join(map(repr, d)) or 'none'})")
    name = d["model"]
    if name == MerlTable.__name__:
        raise ModelFormatError(f"{src}: model = 'MerlTable': {_MERL_WHY}")
    if not isinstance(name, str) or name not in MODELS:
        raise ModelFormatError(f"{src}: model = {name!r}: expected one of {', '.join(sorted(MODELS))}")
    model = _decode_fields(MODELS[name], d["params"], f"{src}: params")
    return typing.cast(Model, model)


def is_serialisable(model: object) -> bool:
    """Whether :func:`to_json_dict` accepts ``model`` (an analytic model of an exact registered class)."""
    return MODELS.get(type(model).__name__) is type(model)


__all__ = ["MODELS", "ModelFormatError", "from_json_dict", "is_serialisable", "to_json_dict"]
