"""Geometry calibration: finding how the rig is really built from images of a reference board.

``gonio calibrate geometry`` runs ``procedure.calibrate_geometry``: it puts a glossy ChArUco board
(``acquisition.board``) on the stage, captures HDR full frames at planned poses (``poses.py``), finds the board's
corners and the lamp's mirror highlight in each (``observe.py``), and fits the joint zero offsets, the
sample's wedge and its offset by least squares against the rig's model (``model.py``, ``fit.py``),
with uncertainties and correlations. The result is ``geometry_calibration.json``
(``rig.instrument.calibration_file``), which a rig file applies with ``[geometry] calibration``.
This package sits above ``rig.run`` (it opens the rig through the run's backends); nothing in the run
imports it.
"""
