"""Fitting models to BRDF samples.

The samples (samples.py), what a fit varies (spec.py), the objective and its solve (problem.py, tall.py,
solve.py), what a fit returns (result.py), model selection over a ladder (select.py), the design of the next
captures (design.py) and the glTF metal-roughness projection (metal_roughness.py).
"""
