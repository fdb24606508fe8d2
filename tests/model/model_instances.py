"""Models with non-default, per-channel (RGB) parameters that the serialisation and the Mitsuba tests share.

test_serialize round-trips each through JSON and test_materials renders each in Mitsuba; either adds its own
further cases. One family each, except Cook-Torrance (whose many forms test_materials lists itself).
"""

from __future__ import annotations

from model import (
    AshikhminShirley,
    CookTorrance,
    KajiyaKay,
    Lafortune,
    LafortuneLobe,
    Lambert,
    MetalRoughness,
    OrenNayar,
    Phong,
    Ward,
)

LAMBERT = Lambert(rho_d=(0.8, 0.5, 0.2))
CT_SCHLICK = CookTorrance(alpha=0.25, fresnel="schlick", f0=(0.9, 0.6, 0.3))
PHONG = Phong(rho_d=(0.3, 0.2, 0.1), rho_s=(0.4, 0.5, 0.6), n=30.0)
WARD = Ward(rho_d=(0.2, 0.3, 0.1), rho_s=(0.3, 0.2, 0.2), alpha_x=0.1, alpha_y=0.3, variant="balanced")
ASHIKHMIN_SHIRLEY = AshikhminShirley(rho_d=(0.5, 0.3, 0.2), rho_s=(0.05, 0.1, 0.2), n_u=50.0, n_v=400.0)
OREN_NAYAR = OrenNayar(rho_d=(0.7, 0.5, 0.3), sigma=0.4)
LAFORTUNE = Lafortune(
    rho_d=(0.2, 0.1, 0.05),
    lobes=(LafortuneLobe(c_x=(-1.0, -0.9, -0.8), c_y=-1.0, c_z=0.9, n=20.0), LafortuneLobe(0.5, 0.5, 0.6, 5.0)),
)
KAJIYA_KAY = KajiyaKay(k_d=(0.3, 0.2, 0.1), k_s=(0.5, 0.4, 0.3), p=40.0, phi_t=0.4)
METAL = MetalRoughness(base_color=(0.9, 0.6, 0.3), metallic=1.0, roughness=0.4)
