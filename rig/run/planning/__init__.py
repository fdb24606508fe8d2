"""Sweep plans: reachability, the order of the points, the arms' swept paths and the calibrated rig's joints."""
