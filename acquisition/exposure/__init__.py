"""Exposure planning: the fewest and shortest frames that reach a target SNR in the ROI.

Plans from a known light level (plan.py, with what a set of frames achieves in snr.py and the vocabulary
in spec.py) or from metering frames (metering.py).
"""
