"""Progress bars with an ETA for the analysis stages that take seconds (fitting the ladder, the figures).

tqdm.auto picks the notebook widget inside Jupyter and the text bar on a terminal; bars write to stderr, so
stdout keeps only the result. A disabled bar (``--quiet``, a batch worker, the tests) costs nothing.
"""

from __future__ import annotations

from typing import Any

from tqdm.auto import tqdm


def stage_bar(total: int, desc: str, enabled: bool, *, unit: str = "it") -> Any:
    """A tqdm bar over ``total`` steps named ``desc`` (use it as a context manager; call update() per step)."""
    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, leave=False, dynamic_ncols=True)
