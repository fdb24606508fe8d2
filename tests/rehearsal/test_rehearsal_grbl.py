"""Every hardware workflow of the README and docs/hardware.md on a GRBL rig, through the rehearsal.

The shipped ``examples/rig_grbl.toml`` (port, folder and ROI changed, see ``workflows.py``) against ``gonio sim
rig``: the camera calibration with the operator's light and lens cap, a run stopped with Ctrl-C at a mid-run
reference and resumed (the controller homes again after the port is opened anew), its analyses, and an
adaptive sweep stopped and resumed. The geometry calibration of ``examples/rig_misaligned.toml`` served on this link.
"""

from __future__ import annotations

import pytest

from tests.rehearsal import workflows as w

pytestmark = [pytest.mark.slow, pytest.mark.mitsuba]


class TestGrbl(w.Workflows):
    """The shared workflows on the GRBL link (the controller homes again each time the port is opened)."""

    link = "grbl"
