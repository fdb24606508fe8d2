"""The stand-in hardware.

Virtual servo buses (dynamixel/, grbl/), the rendered scene (render/), the simulated camera (camera/),
the simulated rig (rig.py) registered as the ``simulated`` backend (backend.py), and the renderer
comparison (comparison*.py). Imports rig, acquisition and model; nothing below imports it.
"""
