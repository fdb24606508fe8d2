"""Offline analysis: runs and MERL files in; fits, a report and exports out.

Sources are loaded into samples (sources.py), the model ladder is fitted and chosen (analyze.py) into one
:class:`analysis.result.Analysis`, which the report's figures (report/plots.py) and page (report/html.py)
read; the chosen material is exported for Mitsuba, glTF and MERL (exports/). Imports rig, acquisition
and model; never the simulator.
"""
