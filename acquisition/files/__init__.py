"""Image files in and out.

Camera RAW through rawpy (raw.py), TIFF and 8-bit images (images.py), a DNG writer (dng.py), the metadata
the readers share (metadata.py) and atomic writes (atomic.py).
"""
