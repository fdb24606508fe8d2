"""The adaptive sweep: rounds of ordinary runs whose points are chosen from what was measured, and its resume state."""
