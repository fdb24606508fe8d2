"""Progress bars with an ETA for the analysis stages that take seconds (fitting the ladder, the figures).

tqdm.auto picks the notebook widget inside Jupyter and the text bar on a terminal; bars write to stderr, so
stdout keeps only the result. A disabled bar (``--quiet``, a batch worker, the tests) costs nothing: it is a
stand-in that does not even import tqdm (tqdm.auto brings asyncio, which ``gonio analyze`` otherwise never loads).
"""

from __future__ import annotations

from typing import Any


class _NoBar:
    """What a disabled bar does: nothing, with the methods the stages call."""

    def update(self, n: int = 1) -> None:
        """Nothing (a step done)."""

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        """Nothing (the step's name)."""

    def close(self) -> None:
        """Nothing (the bar's end)."""

    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def stage_bar(total: int, desc: str, enabled: bool, *, unit: str = "it") -> Any:
    """A tqdm bar over ``total`` steps named ``desc`` (use it as a context manager; call update() per step)."""
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, disable=False, leave=False, dynamic_ncols=True)
