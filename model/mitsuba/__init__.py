"""The models in Mitsuba 3.

The fastest variant that loads on this machine (variant.py), native plugins where a model matches one
(materials.py), and the ``gonio_model`` plugin that renders any other model through its own eval
(plugin.py), the stock-Mitsuba BSDF nearest to any model with its error (projection.py), and any model as an
RGL .bsdf table for Mitsuba's own measured plugin (tabulated.py, in a tensor file: tensor_file.py). The
simulator renders with these; the analysis exports with them.
"""
