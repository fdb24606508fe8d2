"""Loading the HDR merge's compiled passes on first use, with a notice first where they must be compiled.

The numba passes (:mod:`acquisition.hdr.kernel`) serve only images too large for the numpy pass, so they
are imported when such an image is first merged, not at start-up: importing numba is a large part of a start,
and a run on ROI crops never needs it. A caller that shows progress arms a notice with
:func:`notify_before_compiling`; it is called once, before the first load, if numba's on-disk cache does not
hold the passes yet (compiling them is slow on a first run).
"""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType

_notice: list[Callable[[], None]] = []


def notify_before_compiling(notice: Callable[[], None] | None) -> None:
    """Arm ``notice`` (None disarms): called once, before the compiled passes load, if they are not cached."""
    _notice[:] = [] if notice is None else [notice]


def compiled() -> ModuleType:
    """The compiled passes' module, imported on first use (after the armed notice, if they must compile)."""
    import acquisition.hdr.kernel as kernel

    if _notice:
        notice = _notice.pop()
        if not kernel.cached():
            notice()
    return kernel
