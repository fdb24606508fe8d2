"""A Mitsuba 3 BSDF plugin, ``gonio_model``, that renders any model of :mod:`model` through its own ``eval``.

Mitsuba has no Phong, Ward, Oren-Nayar, Ashikhmin-Shirley, Lafortune, Kajiya-Kay or MERL reader, and
its microfacet plugins cover only part of :class:`model.CookTorrance`. This plugin subclasses
``mi.BSDF`` and calls the model's numpy ``eval`` on the directions Mitsuba asks about, so the camera
sees exactly the BRDF the fits and checks use (float64 inside, rounded to float32 on the way out).

Conventions, Mitsuba side: ``si.wi`` and ``wo`` are in the local shading frame, both pointing away
from the surface, and ``eval`` *includes* cos(theta) of ``wo``. When radiance is transported (camera
paths: what the simulated camera renders), ``wo`` points at the light and ``si.wi`` at the camera, so the
plugin returns ``model.eval(wi=wo, wo=si.wi) * cos(theta of wo)``; in importance mode (light paths) the
roles swap. The order matters only for non-reciprocal models (Kajiya-Kay). The local x axis is
Mitsuba's ``si.sh_frame.s`` (for a ``rectangle``, its to_world x axis): anisotropic models read their
tangent from it. Reflection only, front side only: below the horizon the value and the pdf are 0.

Sampling is cosine-weighted over the hemisphere (weight = eval / pdf = pi f_r): adequate for direct
lighting, where emitter sampling finds a point light, not an efficient strategy for sharp lobes.

Running under the llvm variants (measured with mitsuba 3.9.1, drjit 1.5.0). The plugin converts drjit
arrays to numpy, which needs real values. Called from Python (``bsdf.eval(ctx, si, wo)``) the inputs
are ordinary lazily evaluated arrays and that works as is. Called by a C++ integrator during
``mi.render``, the call goes through a vectorised virtual call, which drjit records *symbolically* by
default (``dr.JitFlag.SymbolicCalls``): the Python method then sees placeholder variables that hold no
values, so the plugin raises (``mi.render`` reports "drjit.custom(<mitsuba.python.util._RenderOp>):
error while performing a custom differentiable operation", with the plugin's message as its cause).
With ``SymbolicCalls`` off, drjit evaluates the inputs, calls the plugin once per kernel split with the
real lanes of that BSDF instance, and the numpy round trip works. That suffices for the ``direct``
integrator (whose emitter and BSDF sample counts are C++ loops, unrolled). The ``path`` integrator
wraps its bounces in a ``dr.while_loop``, recorded symbolically unless ``dr.JitFlag.SymbolicLoops`` is
off too; inside a symbolic loop drjit forces calls back to symbolic mode ("currently inside some other
symbolic operation, forcefully running the vectorized call in symbolic mode") and the render fails.
:func:`evaluated_calls` turns both flags off for a block and restores them. Scalar variants need no
flags: Mitsuba calls the plugin once per sample with Python floats.

Speed: under scalar_rgb every sample is one ``model.eval`` from Python, so the plugin suits tests and small
renders; under llvm_ad_rgb a lane batch goes through numpy, an order of magnitude short of a native plugin but
usable for renders (docs/benchmarks.md, the simulator section).

Registration is per variant: a plugin registered under scalar_rgb is unknown under llvm_ad_rgb
(``mi.register_bsdf`` writes to the active variant's plugin manager; the registration survives
switching away and back). :func:`ensure_registered` registers for the active variant once, and
importing this module installs a Mitsuba variant callback that does so for every rgb variant set
later. Models travel through the scene dict as a string key into this module's registry, because
Mitsuba's ``Properties`` hold only numbers, strings, vectors, transforms and Mitsuba objects.

A key is valid only in the process that registered it. For scenes written to disk (Mitsuba XML, a JSON
scene dict) the model can travel instead as its JSON form (:mod:`model.serialize`) in the string property
``model_json`` (:func:`json_plugin_dict`); the plugin then builds its own copy of the model. Such a file
still renders only where this plugin is registered (a Python process that imported this module under an
rgb variant): stock Mitsuba has no ``gonio_model``. MERL tables have no JSON form and keep the key.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import threading
from collections.abc import Iterator
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import numpy.typing as npt

from model.base import BRDF
from model.mitsuba.variant import kind_of
from model.serialize import ModelFormatError, from_json_dict, to_json_dict

PLUGIN = "gonio_model"
#: Property of the scene dict that carries the registry key of the model.
MODEL_KEY = "model"
#: Property of the scene dict (or XML) that carries the model itself as JSON, valid in any process.
MODEL_JSON_KEY = "model_json"

_lock = threading.RLock()
_models: dict[str, BRDF] = {}
_keys_by_id: dict[int, str] = {}
_counter = itertools.count()
_classes: dict[str, type] = {}
_registered: set[str] = set()


def register_model(model: BRDF) -> str:
    """Registry key under which the plugin finds ``model`` (same object, same key; kept for the process)."""
    if not callable(getattr(model, "eval", None)):
        raise TypeError(f"{type(model).__name__} has no eval(wi, wo); the plugin needs a BRDF")
    with _lock:
        # The registry holds the model, so its id cannot be reused by another object meanwhile.
        key = _keys_by_id.get(id(model))
        if key is None:
            key = f"{type(model).__name__}-{next(_counter)}"
            _keys_by_id[id(model)] = key
            _models[key] = model
        return key


def registered_model(key: str) -> BRDF:
    """The model registered under ``key`` by :func:`register_model`."""
    with _lock:
        try:
            return _models[key]
        except KeyError:
            raise KeyError(
                f"{PLUGIN}: no model registered under {key!r}; build the dict with model.mitsuba.materials.to_mitsuba"
            ) from None


def plugin_dict(model: BRDF) -> dict[str, Any]:
    """Mitsuba scene-dict entry of the plugin BSDF for ``model`` (register the plugin before loading)."""
    return {"type": PLUGIN, MODEL_KEY: register_model(model)}


def json_plugin_dict(model: BRDF) -> dict[str, Any]:
    """Scene-dict entry of the plugin carrying ``model`` as JSON text: plain data, usable in any process."""
    return {"type": PLUGIN, MODEL_JSON_KEY: json.dumps(to_json_dict(model))}


def model_from_json(text: str) -> BRDF:
    """The model in a ``model_json`` property (see :func:`json_plugin_dict`); errors name the property."""
    where = f"{PLUGIN} property {MODEL_JSON_KEY!r}"
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ModelFormatError(f"{where}: not valid JSON ({exc}): {text[:80]!r}") from None
    return from_json_dict(doc, source=where)


def rgb_columns(f: npt.ArrayLike, n: int) -> np.ndarray:
    """Model output (n,), (n, 1) or (n, 3) as an (n, 3) float64 array: scalar models fill all channels."""
    a = np.asarray(f, dtype=np.float64).reshape(n, -1)
    if a.shape[1] == 1:
        return np.broadcast_to(a, (n, 3))
    if a.shape[1] != 3:
        raise ValueError(f"{PLUGIN}: the model returned {a.shape[1]} channels; Mitsuba's rgb variants need 1 or 3")
    return a


def eval_cos(model: BRDF, wi: npt.ArrayLike, wo: npt.ArrayLike, importance: bool = False) -> np.ndarray:
    """What the plugin's ``eval`` returns, in 1/sr: f_r * cos(theta of wo) for Mitsuba's (si.wi, wo), (N, 3).

    ``wi`` is Mitsuba's ``si.wi`` and ``wo`` its ``wo``, unit vectors (N, 3) or (3,) in the local frame;
    in radiance mode (``importance`` False) ``wo`` is the light direction, so it is the model's wi.
    """
    a = np.atleast_2d(np.asarray(wi, dtype=np.float64))
    b = np.atleast_2d(np.asarray(wo, dtype=np.float64))
    a, b = np.broadcast_arrays(a, b)
    light, view = (a, b) if importance else (b, a)
    f = rgb_columns(model.eval(light, view), len(a))
    return f * np.maximum(b[:, 2:3], 0.0)


@contextlib.contextmanager
def evaluated_calls() -> Iterator[None]:
    """Inside the block drjit calls BSDFs with real arrays (SymbolicCalls and SymbolicLoops off)."""
    with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, False), dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, False):
        yield


def _to_numpy(v: Any, jit: bool) -> np.ndarray:
    """A drjit 3-vector (scalar or N lanes) as an (N, 3) float64 array."""
    if jit:
        return np.array(v, dtype=np.float64).reshape(3, -1).T
    return np.array([[v.x, v.y, v.z]], dtype=np.float64)


def _make_class(variant: str) -> type:
    """The plugin class bound to one variant's types (a subclass of that variant's ``mi.BSDF``)."""
    ns = getattr(mi, variant)
    jit = bool(dr.is_jit_v(ns.Float))
    flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
    lobes = (mi.BSDFFlags.GlossyReflection, mi.BSDFFlags.DiffuseReflection)
    importance_mode = mi.TransportMode.Importance

    class GonioModelBSDF(ns.BSDF):  # type: ignore[name-defined]
        """Mitsuba BSDF that evaluates a :mod:`model` BRDF with numpy (see the module docstring)."""

        def __init__(self, props: Any) -> None:
            ns.BSDF.__init__(self, props)
            if MODEL_KEY in props:
                self.key = str(props[MODEL_KEY])
                self.model = registered_model(self.key)
            elif MODEL_JSON_KEY in props:
                self.key = ""
                self.model = model_from_json(str(props[MODEL_JSON_KEY]))
            else:
                raise KeyError(
                    f"{PLUGIN}: the scene dict needs a {MODEL_KEY!r} key (use to_mitsuba) or a "
                    f"{MODEL_JSON_KEY!r} string (use json_plugin_dict)"
                )
            self.m_flags = flags
            self.m_components = [flags]

        def _enabled(self, ctx: Any) -> bool:
            return any(ctx.is_enabled(lobe, 0) for lobe in lobes)

        def _value(self, ctx: Any, si: Any, wo: Any, active: Any) -> Any:
            """f_r cos(theta_o) as a Color3f of the variant, zero where inactive or below the horizon."""
            importance = ctx.mode == importance_mode
            if not jit:
                if not active or si.wi.z <= 0.0 or wo.z <= 0.0:
                    return ns.Color3f(0.0)
                f = eval_cos(self.model, _to_numpy(si.wi, jit), _to_numpy(wo, jit), importance)[0]
                return ns.Color3f(*f.tolist())
            if dr.flag(dr.JitFlag.SymbolicScope):
                raise RuntimeError(
                    f"{PLUGIN} evaluates its model with numpy and cannot be traced symbolically: render "
                    "inside model.mitsuba.plugin.evaluated_calls() (drjit SymbolicCalls and SymbolicLoops off)"
                )
            f = eval_cos(self.model, _to_numpy(si.wi, jit), _to_numpy(wo, jit), importance)
            value = ns.Color3f(np.ascontiguousarray(f.T, dtype=np.float32))
            return dr.select(active, value, 0.0)

        def _pdf(self, si: Any, wo: Any) -> Any:
            pdf = ns.warp.square_to_cosine_hemisphere_pdf(wo)
            return dr.select((si.wi.z > 0.0) & (wo.z > 0.0), pdf, 0.0)

        def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """f_r * cos(theta_o) in 1/sr (Mitsuba's convention)."""
            if not self._enabled(ctx):
                return ns.Color3f(0.0)
            return self._value(ctx, si, wo, active)

        def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> Any:
            """Density of :meth:`sample` in 1/sr: cos(theta_o) / pi over the upper hemisphere."""
            if not self._enabled(ctx):
                return ns.Float(0.0)
            return dr.select(active, self._pdf(si, wo), 0.0)

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True) -> tuple[Any, Any]:
            """(eval, pdf) in one call, as the direct and path integrators ask."""
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True) -> tuple[Any, Any]:
            """A cosine-weighted direction and its weight eval / pdf (= pi f_r)."""
            bs = dr.zeros(ns.BSDFSample3f)
            if not self._enabled(ctx):
                return bs, ns.Color3f(0.0)
            active = active & (si.wi.z > 0.0)
            bs.wo = ns.warp.square_to_cosine_hemisphere(sample2)
            bs.pdf = dr.select(active, self._pdf(si, bs.wo), 0.0)
            bs.eta = 1.0
            bs.sampled_type = ns.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = 0
            active = active & (bs.pdf > 0.0)
            value = self._value(ctx, si, bs.wo, active)
            return bs, dr.select(active, value / dr.select(active, bs.pdf, 1.0), 0.0)

        def traverse(self, callback: Any) -> None:
            """No differentiable parameters: the model is a frozen numpy object."""

        def to_string(self) -> str:
            """Short description with the model's repr."""
            return f"GonioModelBSDF[{self.model!r}]"

    GonioModelBSDF.__name__ = GonioModelBSDF.__qualname__ = f"GonioModelBSDF_{variant}"
    return GonioModelBSDF


def ensure_registered() -> str:
    """Register the plugin for the active Mitsuba variant (once per variant); returns the variant name."""
    variant = mi.variant()
    if variant is None:
        raise RuntimeError(f"{PLUGIN}: no Mitsuba variant is set; call mi.set_variant (or use_variant) first")
    if kind_of(variant) != "rgb":
        raise ValueError(f"{PLUGIN} returns RGB values; variant {variant!r} is not an rgb variant")
    with _lock:
        if variant not in _registered:
            cls = _classes.get(variant) or _make_class(variant)
            _classes[variant] = cls
            mi.register_bsdf(PLUGIN, lambda props: cls(props))
            _registered.add(variant)
    return variant


def _on_variant_change(old: str | None, new: str | None) -> None:
    """Mitsuba variant callback: register for every rgb variant as it is set (never raises)."""
    if new is not None and kind_of(new) == "rgb":
        with contextlib.suppress(Exception):  # a failure here would abort mi.set_variant itself
            ensure_registered()


def _install_callback() -> None:
    add = getattr(getattr(mi, "detail", None), "add_variant_callback", None)
    if add is not None:
        add(_on_variant_change)
    variant = mi.variant()
    if variant is not None and kind_of(variant) == "rgb":
        ensure_registered()


_install_callback()
