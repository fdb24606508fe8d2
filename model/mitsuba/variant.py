"""Choose the fastest Mitsuba 3 variant that loads on this machine, with a fallback and an override.

Order of preference for a kind (``"rgb"``, ``"spectral"``, ...): ``llvm_ad_<kind>`` (vectorised,
JIT-compiled, far more throughput than scalar from Python), then ``scalar_<kind>``, which needs
nothing beyond the wheel. The llvm variants need libLLVM >= 16 at run time: without any libLLVM
``mi.set_variant`` raises, and with LLVM 15 the variant sets but the process *aborts* in code
generation at the first BSDF kernel (measured here with libLLVM-15.so.1), which no ``except`` can
catch. So a probe sets the variant, catches the exception, and checks drjit's libLLVM version.

Probing loads the variant, so each answer is cached for the life of the
process (libLLVM is loaded once per process; a failed load is not retried by drjit either).

Precedence in :func:`pick_variant`: the environment variable :data:`ENV_VAR`
(``GONIO_MITSUBA_VARIANT``) forces one variant for a whole run, e.g. to reproduce a result on
``scalar_rgb`` (a forced variant that does not load is an error naming it and the cause); else the
caller's ``prefer`` is tried first; else the fastest of :data:`BACKENDS` that loads. Probing leaves
the active variant as it was (when none was active, the last variant probed stays set: Mitsuba
cannot unset one); :func:`use_variant` sets one for a block and restores the previous.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

import drjit as dr
import mitsuba as mi

from model.errors import GonioError
from model.runtime import drjit_thread_budget

drjit_thread_budget()  # a Dask worker's OMP_NUM_THREADS=1 holds for Dr.Jit's pool too

ENV_VAR = "GONIO_MITSUBA_VARIANT"
#: Backends tried by :func:`pick_variant`, fastest first.
BACKENDS: tuple[str, ...] = ("llvm_ad", "scalar")
#: Oldest libLLVM major version whose code generation handles Mitsuba's kernels.
MIN_LLVM_MAJOR = 16
LLVM_HINT = (
    "the llvm variants need libLLVM >= 16: install it (Debian/Ubuntu: `apt-get install libllvm19`) "
    "or point DRJIT_LIBLLVM_PATH at a libLLVM.so"
)
_BACKEND_PREFIXES: tuple[str, ...] = ("scalar_", "llvm_ad_", "cuda_ad_", "llvm_", "cuda_")

_lock = threading.RLock()
_reasons: dict[str, str | None] = {}


class VariantUnavailable(GonioError, RuntimeError):
    """A Mitsuba variant that was asked for does not load here; the message says why."""


def kind_of(name: str) -> str | None:
    """The colour representation of a variant name (``"rgb"`` for ``"llvm_ad_rgb"``); None if unknown."""
    for prefix in _BACKEND_PREFIXES:
        if name.startswith(prefix):
            return name[len(prefix) :]
    return None


def _try_load(name: str) -> str | None:
    """Set the variant once to see whether it loads; the reason it does not, or None if it does."""
    built = list(mi.variants())
    if name not in built:
        return f"not a variant of this Mitsuba build (built: {', '.join(built)})"
    hint = f"; {LLVM_HINT}" if name.startswith("llvm") else ""
    previous = mi.variant()
    try:
        mi.set_variant(name)
    except Exception as exc:  # drjit raises ImportError today; any failure means "does not load"
        return f"{type(exc).__name__}: {exc}{hint}"
    try:
        if name.startswith("llvm"):
            version = tuple(dr.detail.llvm_version())
            if version[0] < MIN_LLVM_MAJOR:
                found = ".".join(str(v) for v in version)
                return f"libLLVM {found} is too old (it aborts in code generation){hint}"
    finally:
        # A failed set_variant leaves the previous variant active; a successful one must be undone.
        if previous is not None and previous != name:
            mi.set_variant(previous)
    return None


def unavailable_reason(name: str) -> str | None:
    """Why variant ``name`` does not load here, or None when it does (probed once, then cached)."""
    with _lock:
        if name not in _reasons:
            _reasons[name] = _try_load(name)
        return _reasons[name]


def clear_cache() -> None:
    """Forget every probe result (for tests; drjit itself never retries a failed libLLVM load)."""
    with _lock:
        _reasons.clear()


def _require(name: str, source: str) -> str:
    """Return ``name`` if it loads, else raise :class:`VariantUnavailable` naming it and the cause."""
    reason = unavailable_reason(name)
    if reason is not None:
        raise VariantUnavailable(f"Mitsuba variant {name!r} ({source}) does not load: {reason}")
    return name


def _check_kind(name: str, kind: str, source: str) -> None:
    """Reject a forced or preferred variant of another colour representation than asked for."""
    # An unrecognised name is left to the probe, whose message lists the variants that exist.
    found = kind_of(name)
    if found is not None and found != kind:
        raise VariantUnavailable(
            f"Mitsuba variant {name!r} ({source}) is a {found!r} variant; the caller needs {kind!r}"
        )


def candidates(kind: str = "rgb") -> list[str]:
    """Variant names tried for ``kind``, fastest first."""
    return [f"{backend}_{kind}" for backend in BACKENDS]


def available_variants(kind: str | None = "rgb") -> list[str]:
    """Variants of ``kind`` (every built variant if None) that actually load here, fastest first."""
    names = list(mi.variants()) if kind is None else candidates(kind)
    return [name for name in names if unavailable_reason(name) is None]


def pick_variant(kind: str = "rgb", prefer: str | None = None) -> str:
    """Name of the variant to use: $GONIO_MITSUBA_VARIANT if set, else ``prefer``, else the fastest."""
    forced = os.environ.get(ENV_VAR, "").strip()
    if forced:
        source = f"forced by {ENV_VAR}"
        _check_kind(forced, kind, source)
        return _require(forced, source)
    names = candidates(kind)
    if prefer is not None:
        # A preference, not a demand: it falls back like the defaults (force with the variable).
        _check_kind(prefer, kind, "preferred")
        names = [prefer, *(n for n in names if n != prefer)]
    reasons: dict[str, str | None] = {}
    for name in names:  # in order, so a faster variant that loads spares probing the slower ones
        reasons[name] = unavailable_reason(name)
        if reasons[name] is None:
            return name
    detail = "; ".join(f"{name}: {reason}" for name, reason in reasons.items())
    raise VariantUnavailable(f"no Mitsuba {kind!r} variant loads here ({detail})")


@contextlib.contextmanager
def use_variant(name: str) -> Iterator[str]:
    """Make ``name`` the active Mitsuba variant inside the block, then restore the previous one."""
    _require(name, "requested")
    previous = mi.variant()
    if previous == name:
        # Switching is not free (Mitsuba re-imports its Python plugins): skip no-ops.
        yield name
        return
    mi.set_variant(name)
    try:
        yield name
    finally:
        # Mitsuba cannot unset a variant, so with none active before, ``name`` stays active after.
        if previous is not None:
            mi.set_variant(previous)
