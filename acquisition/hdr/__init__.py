"""The HDR merge of a bracket.

Checking the bracket (bracket.py), the noise-optimal linear merge (merge.py), its pass in numpy for ROI-sized
images (small.py) and compiled for larger ones (kernel.py, loaded on first use by compiled.py; prepared.py
picks one), the clip level measured from the data (saturation.py), and the 8-bit path with a camera response
curve (response.py).
"""
