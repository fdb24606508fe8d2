"""The HDR merge of a bracket.

Checking the bracket (bracket.py), the noise-optimal linear merge (merge.py) and its compiled pass
(kernel.py), the clip level measured from the data (saturation.py), and the 8-bit path with a camera
response curve (response.py).
"""
