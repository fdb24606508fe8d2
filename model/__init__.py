"""gonio.model: physically based reflectance models and the radiometry of one measurement.

Pure functions and small frozen dataclasses over numpy arrays; no I/O beyond MERL files, no hardware.
Conventions (docs/architecture.md): local frame with z the sample normal, both directions pointing away from
the surface, ``eval`` returns f_r in 1/sr without the cosine, radians inside and degrees at the user
boundary, float64 by default and float32 accepted.
"""

import model.runtime  # noqa: F401 (first: sets the thread pools' policy before numba or BLAS start)
from model._params import ParameterError
from model.ashikhmin_shirley import AshikhminShirley
from model.base import BRDF, Model
from model.blinn_phong import BlinnPhong
from model.cook_torrance import CookTorrance, alpha_from_roughness, walter_from_1982
from model.kajiya_kay import KajiyaKay
from model.lafortune import Lafortune, LafortuneLobe
from model.lambert import Lambert
from model.merl import MerlTable, read_merl, write_merl
from model.metal_roughness import MetalRoughness
from model.metalness_mix import MetalnessMix
from model.oren_nayar import OrenNayar
from model.phong import Phong
from model.predict import predict_radiance, predict_radiance_deg
from model.radiometry import PointLight, SpotLight
from model.ward import Ward

__all__ = [
    "BRDF",
    "AshikhminShirley",
    "BlinnPhong",
    "CookTorrance",
    "KajiyaKay",
    "Lafortune",
    "LafortuneLobe",
    "Lambert",
    "MerlTable",
    "MetalRoughness",
    "MetalnessMix",
    "Model",
    "OrenNayar",
    "ParameterError",
    "Phong",
    "PointLight",
    "SpotLight",
    "Ward",
    "alpha_from_roughness",
    "predict_radiance",
    "predict_radiance_deg",
    "read_merl",
    "walter_from_1982",
    "write_merl",
]
