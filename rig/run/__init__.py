"""A run on the instrument.

Rig and sweep files (config.py, config_schema.py), sweeps and plans (sweeps.py, plan.py, plan_order.py),
one measurement (measure.py), the reference target (reference.py), the runner (runner.py), the run store
(store.py, store_formats.py, table.py), the adaptive sweep (adaptive.py), the backends a rig file names
(backends.py, hardware.py) and the session that wires them together (session.py).
"""
