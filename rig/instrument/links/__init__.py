"""Links: the devices that move the rig's axes (Dynamixel bus, GRBL controller), behind one interface."""
