"""The instrument and a run on it.

``rig.instrument``: axes, clocks, geometry, kinematics and the motion links. ``rig.run``: rig and sweep
files, sweeps and plans, the runner, the run store, and the session that wires a rig file to its backend.
Imports acquisition and model.
"""
