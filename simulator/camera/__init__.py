"""The simulated camera.

The sensor model (sensor.py) and a camera that turns rendered radiance into the frames of a bracket
(simulated.py).
"""
