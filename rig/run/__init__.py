"""A run on the instrument.

``session.py`` is the front door (``start_run``, ``resume_run``, ``make_plan``); ``calibrate.py`` is the camera
calibration's procedure. The families below it: ``config/`` (rig and sweep files, the sweep kinds), ``planning/``
(reachability, order, swept paths), ``backends/`` (what a rig file opens), ``measuring/`` (the runner and one
reading), ``storage/`` (the run directory and its journal), ``tables/`` (the calibrated samples table) and
``adaptive/`` (sweeps that choose their points from measurements).
"""
