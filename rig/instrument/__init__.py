"""The instrument as the controller sees it.

Axes (axis.py), clocks (clock.py), the rig's geometry (geometry.py), kinematics with reachability
(kinematics*.py) and the links that move the joints (links/). Imports model only.
"""
