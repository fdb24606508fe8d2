"""The measuring loop: guarded moves, readings, reference readings, progress, and the rig left safe on every stop."""
