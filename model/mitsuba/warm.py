"""Mitsuba's first-use costs paid ahead: what a process that will export a model it does not know yet can build now.

The first tabulation and the first evaluations of a BSDF in a process cost more than later ones (plugins
loaded, warps and JIT kernels built); ``gonio analyze``'s export standby pays them during the fit
(analysis.exports.write.prepare_exports) instead of after it.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from model.cook_torrance import CookTorrance
from model.mitsuba.materials import to_mitsuba
from model.mitsuba.projection import GRID_PHI_I_DEG, grid_pairs, mitsuba_values
from model.mitsuba.tabulated import TabulationGrid, measured_bsdf, tabulate
from model.mitsuba.variant import pick_variant

#: What :func:`warm_up` tabulates: a glossy isotropic model on the smallest grid, so every Mitsuba object and kernel
#: a tabulation and its error use is built once, at little cost (its values are thrown away).
WARM_UP_GRID = TabulationGrid(samples=4, theta_i=2, phi_i=2, ndf=8)


def warm_up(variant: str | None = None) -> None:
    """Build once what Mitsuba builds at the first stock form of a process (plugins, warps, JIT kernels).

    For a process that will export a model it does not know yet (``gonio analyze``'s export standby, during the
    fit): the first tabulation and the first evaluations of a BSDF cost more than the later ones.
    """
    name = variant or pick_variant("rgb")
    glossy = CookTorrance(alpha=0.3, fresnel="schlick", f0=0.5, rho_d=0.1)
    table = tabulate(glossy, WARM_UP_GRID, variant=name)
    wi, wo = (a[:64] for a in grid_pairs(GRID_PHI_I_DEG[:1]))
    with tempfile.TemporaryDirectory(prefix="gonio-bsdf-") as tmp:
        path = table.write(Path(tmp) / "material.bsdf")
        mitsuba_values(measured_bsdf(str(path)), wi, wo, name)
    # The family every projection lands in (diffuse + GGX conductor: a blendbsdf), native as it is.
    family = CookTorrance(alpha=0.3, fresnel="conductor", eta=(0.2, 0.4, 1.6), k=(2.2, 2.3, 1.9), rho_d=0.1)
    mitsuba_values(to_mitsuba(family).bsdf, wi, wo, name)
