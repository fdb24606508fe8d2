"""Rig and sweep files: the schema, loading with errors naming file, key and value, the sweep kinds' directions."""
