"""The numba kernel of CookTorrance against the numpy reference path (Model.eval), and its fallbacks."""

import itertools
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from model import kernels
from model.base import Model
from model.checks import extreme_pairs, random_hemisphere
from model.cook_torrance import CookTorrance

CONFIGS = list(itertools.product(kernels.DISTRIBUTIONS, kernels.MASKINGS, kernels.FRESNELS))

# Parameter sets per Fresnel kind, grouped by channel count (each count is one compiled loop).
# They include the extremes: eta = 1 (no interface), k = 200 (k >> 1), eta < 1 (total internal
# reflection), f0 at 0 and 1, and a Lambertian term.
SCALAR = {
    "conductor": [{"eta": 1.0, "k": 0.0}, {"eta": 0.2, "k": 3.0}, {"eta": 1.5, "k": 200.0, "rho_d": 0.3}],
    "dielectric": [{"eta": 1.0}, {"eta": 1.5, "rho_d": 0.3}, {"eta": 0.7}],
    "schlick": [{"f0": 0.04}, {"f0": 1.0, "rho_d": 0.3}],
}
RGB = {
    "conductor": [{"eta": (1.657, 1.0, 0.2), "k": (9.224, 0.0, 200.0), "rho_d": (0.1, 0.0, 0.5)}],
    "dielectric": [{"eta": (1.5, 1.0, 0.7), "rho_d": (0.1, 0.0, 0.5)}],
    "schlick": [{"f0": (0.0, 0.5, 1.0), "rho_d": (0.1, 0.0, 0.5)}],
}
ALPHAS = (1e-6, 1e-3, 0.3, 5.0)
FORMS = ("walter", "cook_torrance_1982")


def _reflect(v):
    return np.stack([-v[:, 0], -v[:, 1], v[:, 2]], axis=-1)


def _pairs(dtype):
    """Random pairs plus the extremes: grazing (cos 0, 1e-12), equal, opposite, mirror and near-mirror."""
    rng = np.random.default_rng(7)
    wi, wo = random_hemisphere(1500, rng), random_hemisphere(1500, rng)
    ex_i, ex_o = extreme_pairs(np.float64)
    mirror_i = random_hemisphere(200, rng)
    near = mirror_i + rng.normal(scale=1e-7, size=mirror_i.shape)
    near /= np.linalg.norm(near, axis=-1, keepdims=True)
    # wo = wi (retro-reflection), exact mirror (the peak at cos_h = 1) and a 1e-7 perturbation of it,
    # where D at the clamped alpha = 1e-4 is most sensitive to rounding.
    # Far below float32's range (there they round to 0, below the horizon): where the Beckmann
    # Lambda argument hits its lower clip and 4 cos_i cos_o its floor.
    deep = np.array([[np.sqrt(1.0 - e * e), 0.0, e] for e in (1e-160, 1e-200, 1e-300, 5e-324)])
    deep = np.concatenate([deep, deep * [-1.0, 1.0, 1.0]])
    oblique = np.tile([0.6, 0.0, 0.8], (len(deep), 1))
    a = np.concatenate([wi, ex_i, wi[:200], mirror_i, near, deep, deep])
    b = np.concatenate([wo, ex_o, wi[:200], _reflect(mirror_i), _reflect(mirror_i), deep[::-1], oblique])
    return a.astype(dtype), b.astype(dtype)


def _models(distribution, masking, fresnel, params):
    for kw, alpha, form in itertools.product(params, ALPHAS, FORMS):
        yield CookTorrance(
            alpha=alpha, distribution=distribution, masking=masking, fresnel=fresnel, form=form, **kw
        )


def _assert_matches(model, wi, wo, rtol):
    got = model.compiled_eval(wi, wo)
    assert got is not None, model
    ref = Model.eval(model, wi, wo)
    assert got.shape == ref.shape and got.dtype == ref.dtype
    np.testing.assert_allclose(got, ref, rtol=rtol, atol=0, err_msg=repr(model))
    # The public eval agrees whichever path its batch size selects (see KERNEL_MIN_PAIRS).
    np.testing.assert_allclose(model.eval(wi, wo), got, rtol=rtol, atol=0, err_msg=repr(model))


@pytest.mark.parametrize("distribution,masking,fresnel", CONFIGS)
def test_float64_matches_numpy_to_1e_12(distribution, masking, fresnel):
    wi, wo = _pairs(np.float64)
    for params in (SCALAR[fresnel], RGB[fresnel]):
        for model in _models(distribution, masking, fresnel, params):
            _assert_matches(model, wi, wo, rtol=1e-12)


@pytest.mark.parametrize("distribution,masking,fresnel", CONFIGS)
def test_float32_matches_numpy_float32_to_1e_5(distribution, masking, fresnel):
    wi, wo = _pairs(np.float32)
    for model in _models(distribution, masking, fresnel, RGB[fresnel]):
        _assert_matches(model, wi, wo, rtol=1e-5)


def test_float64_is_bit_identical_where_no_special_function_is_involved():
    # GGX needs no exp or erfc, whose libm and numpy/scipy roundings may differ in the last bit.
    wi, wo = _pairs(np.float64)
    for model in _models("ggx", "smith", "conductor", RGB["conductor"]):
        np.testing.assert_array_equal(model.compiled_eval(wi, wo), Model.eval(model, wi, wo))


def test_below_horizon_and_non_finite_inputs_give_what_numpy_gives():
    model = CookTorrance(alpha=0.3, eta=(1.657, 0.88, 0.521), k=(9.224, 6.27, 4.837), rho_d=0.2)
    up = np.array([0.6, 0.0, 0.8])
    bad = [[0.6, 0.0, -0.8], [0.0, 0.0, -1.0], [np.nan, 0.0, 0.8], [0.0, 0.0, np.nan], [np.inf, 0.0, 0.8]]
    wi = np.array(bad + [up] * len(bad))
    wo = np.array([up] * len(bad) + bad)
    got = model.compiled_eval(wi, wo)
    np.testing.assert_array_equal(got, Model.eval(model, wi, wo))  # NaN where numpy has NaN
    assert np.all(got[[0, 1, 5, 6]] == 0)


@pytest.mark.parametrize(
    "shape_i,shape_o",
    [((3,), (3,)), ((4, 5, 3), (4, 5, 3)), ((3,), (7, 3)), ((2, 7, 3), (1, 3)), ((0, 3), (0, 3))],
)
def test_shapes_follow_the_numpy_path(shape_i, shape_o):
    rng = np.random.default_rng(1)
    wi = random_hemisphere(int(np.prod(shape_i[:-1])), rng).reshape(shape_i)
    wo = random_hemisphere(int(np.prod(shape_o[:-1])), rng).reshape(shape_o)
    for model in (CookTorrance(alpha=0.2), CookTorrance(alpha=0.2, eta=(1.5, 0.9, 0.5), k=(3.0, 2.0, 1.0))):
        got = model.compiled_eval(wi, wo)
        assert got is not None
        ref = Model.eval(model, wi, wo)
        assert got.shape == ref.shape
        np.testing.assert_array_equal(got, ref)


def test_non_contiguous_and_integer_inputs_are_converted_and_left_untouched():
    rng = np.random.default_rng(2)
    wi = random_hemisphere(40, rng)[::2]
    wo = np.asfortranarray(random_hemisphere(20, rng))
    before = wi.copy()
    model = CookTorrance(alpha=0.3)
    np.testing.assert_array_equal(model.eval(wi, wo), Model.eval(model, wi, wo))
    np.testing.assert_array_equal(wi, before)
    z = np.array([[0, 0, 1]])
    assert model.eval(z, z).dtype == np.float64
    np.testing.assert_array_equal(model.eval(z, z), Model.eval(model, z, z))


@pytest.mark.parametrize(
    "kw", [{"distribution": "blinn_phong"}, {"masking": "v_groove"}, {"distribution": "blinn_phong", "masking": "none"}]
)
def test_unsupported_configurations_fall_back_to_numpy(kw):
    model = CookTorrance(alpha=0.3, eta=(1.5, 0.9, 0.5), k=(3.0, 2.0, 1.0), **kw)
    wi, wo = _pairs(np.float64)
    assert model.compiled_eval(wi, wo) is None
    np.testing.assert_array_equal(model.eval(wi, wo), Model.eval(model, wi, wo))


def test_other_broadcasts_fall_back_to_numpy():
    rng = np.random.default_rng(3)
    wi = random_hemisphere(5, rng).reshape(5, 1, 3)
    wo = random_hemisphere(4, rng).reshape(1, 4, 3)
    model = CookTorrance(alpha=0.3)
    assert model.compiled_eval(wi, wo) is None
    f = model.eval(wi, wo)
    assert f.shape == (5, 4)
    np.testing.assert_array_equal(f, Model.eval(model, wi, wo))


def test_malformed_directions_raise_the_numpy_error():
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        CookTorrance().eval(np.zeros((4, 2)), np.zeros((4, 2)))


def test_a_subclass_that_changes_the_physics_keeps_its_own_path():
    class Doubled(CookTorrance):
        def specular(self, p):
            return 2.0 * super().specular(p)

    model, plain = Doubled(alpha=0.3), CookTorrance(alpha=0.3)
    wi, wo = _pairs(np.float64)
    assert model.compiled_eval(wi, wo) is None
    np.testing.assert_allclose(model.eval(wi, wo), 2.0 * plain.eval(wi, wo), rtol=1e-15)


def test_warm_up_compiles_the_default_configuration():
    kernels.warm_up()
    kernels.warm_up(channels=3)
    z = np.array([0.0, 0.0, 1.0])
    np.testing.assert_array_equal(CookTorrance().eval(z, z), Model.eval(CookTorrance(), z, z))


def test_eval_routes_large_batches_to_the_kernel_and_small_ones_to_numpy(monkeypatch):
    from model import cook_torrance as ct_module

    calls = []
    real = kernels.microfacet
    monkeypatch.setattr(kernels, "microfacet", lambda *a: calls.append(1) or real(*a))
    model = CookTorrance(alpha=0.2)
    rng = np.random.default_rng(0)
    big = rng.normal(size=(ct_module.KERNEL_MIN_PAIRS, 3))
    big[:, 2] = np.abs(big[:, 2])
    big /= np.linalg.norm(big, axis=1, keepdims=True)
    model.eval(big[:10], big[:10][::-1])
    assert calls == []
    np.testing.assert_array_equal(model.eval(big, big[::-1]), Model.eval(model, big, big[::-1]))
    assert calls == [1]


VECTORISED = """
import re, numpy as np
from model.kernels import MicrofacetParams, _compiled, _config, microfacet
z = np.array([[0.0, 0.6, 0.8], [0.6, 0.0, 0.8]])
for fresnel in ("conductor", "dielectric"):
    microfacet(z, z[::-1].copy(), "ggx", "smith", MicrofacetParams(fresnel, eta=(0.2, 0.4, 1.4), k=(3.0, 2.0, 1.0),
                                                                   rho_d=(0.1, 0.2, 0.3), channels=3))
    (asm,) = _compiled(*_config("ggx", "smith", fresnel), 3).inspect_asm().values()
    print(fresnel, len(re.findall(r"\\bvsqrtpd\\b", asm)), len(re.findall(r"\\bvgather|\\bvscatter", asm)))
"""


@pytest.mark.skipif(platform.machine() != "x86_64", reason="reads x86 assembly")
def test_the_ggx_loops_vectorise_without_gathers_or_scatters(tmp_path):
    # The speed of the kernel is its vector loop: a per-channel value read from an array inside it kept the
    # dielectric loop scalar on AVX2 and made every loop gather and scatter on AVX-512 (several times slower).
    # Compiled afresh (numba's cache keeps no assembly), for the host's ISA.
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", VECTORISED], capture_output=True, text=True, timeout=600, env=env,
                          cwd=Path(__file__).resolve().parents[2])  # fmt: skip
    assert done.returncode == 0, done.stderr
    for line in done.stdout.splitlines():
        fresnel, packed_sqrt, gathers = line.split()
        assert int(packed_sqrt) > 0, f"{fresnel}: no packed square root, the loop is scalar"
        assert int(gathers) == 0, f"{fresnel}: {gathers} gathers or scatters in the loop"
    assert len(done.stdout.splitlines()) == 2, done.stdout
