"""The Mitsuba 3 scene of the rig at one pose.

What the scene needs beyond the rig geometry (spec.py), the camera as a pinhole model (view.py), the
scene (scene.py) and the renderer with its cache (renderer.py).
"""
