"""What a rig file opens: registered backends, hardware links and cameras, the reference target, the flat source."""
