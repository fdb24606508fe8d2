"""A virtual Dynamixel Protocol 2.0 bus of XM430-W350 servos on a pseudo-terminal.

``open_virtual_bus`` serves servos that any Protocol 2.0 client (``dynamixel_sdk`` included) reaches by
opening ``bus.port``; ``bus.servo(id)`` gives the Python side: faults, mechanics, state and control table.
"""

from __future__ import annotations

from simulator.dynamixel.bus import BusStats, VirtualDynamixelBus, open_virtual_bus, serve_forever
from simulator.dynamixel.faults import HardwareError, ServoFaults, ServoMechanics
from simulator.dynamixel.motion import ServoState
from simulator.dynamixel.profile import ProfileType
from simulator.dynamixel.servo import VirtualServo

__all__ = [
    "BusStats",
    "HardwareError",
    "ProfileType",
    "ServoFaults",
    "ServoMechanics",
    "ServoState",
    "VirtualDynamixelBus",
    "VirtualServo",
    "open_virtual_bus",
    "serve_forever",
]
