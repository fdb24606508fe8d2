"""A virtual GRBL 1.1 controller on a pseudo-terminal.

G-code parsing (gcode.py), ``$`` settings (settings.py), motion (motion.py), the controller (core.py,
controller.py) and the pty server (server.py).
"""
