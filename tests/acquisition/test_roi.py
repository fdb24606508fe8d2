import numpy as np
import pytest

from acquisition.noise import SensorNoise
from acquisition.roi import RoiError, box_mask, circle_mask, reduce_roi, validate_box

NOISE = SensorNoise()


def hdr_like(truth, rng, exposure_s=0.01):
    """A one-frame linear 'merge' of a truth image (counts/s): noisy radiance and its per-pixel variance."""
    s = truth * exposure_s
    var_dn2 = NOISE.variance_dn2(s, exposure_s)
    rad = (s + rng.normal(0.0, 1.0, truth.shape) * np.sqrt(var_dn2)) / exposure_s
    # The merge reports the variance from its own (noisy) estimate, as a real one does.
    return rad, NOISE.variance_dn2(np.maximum(rad * exposure_s, 0), exposure_s) / exposure_s**2


def test_box_validation_names_box_and_shape():
    assert validate_box((1, 2, 5, 6), (10, 8)) == (1, 2, 5, 6)
    msg = r"ROI box \(x0, y0, x1, y1\) = .* does not fit an image of shape \(10, 8, 3\)"
    for bad in [(0, 0, 9, 5), (3, 0, 3, 5), (-1, 0, 4, 4), (0, 4, 4, 2)]:
        with pytest.raises(RoiError, match=msg):
            validate_box(bad, (10, 8, 3))
    with pytest.raises(RoiError, match="4 numbers"):
        validate_box((1, 2, 3), (10, 8))
    with pytest.raises(RoiError, match="whole numbers"):
        validate_box((0.5, 0, 2, 2), (10, 8))
    with pytest.raises(RoiError, match=r"expected \(H, W\) or \(H, W, C\)"):
        reduce_roi(np.zeros(5), np.zeros(5), (0, 0, 1, 1))


def test_mask_validation():
    img = np.ones((6, 7))
    with pytest.raises(RoiError, match=r"mask has shape \(7, 6\).*\(6, 7\)"):
        reduce_roi(img, img, np.ones((7, 6), dtype=bool))
    with pytest.raises(RoiError, match="dtype"):
        reduce_roi(img, img, np.ones((6, 7), dtype=int))
    with pytest.raises(RoiError, match="no pixel"):
        reduce_roi(img, img, np.zeros((6, 7), dtype=bool))
    with pytest.raises(RoiError, match="variance has shape"):
        reduce_roi(img, np.ones((6, 7, 3)), (0, 0, 2, 2))


def test_box_and_circle_masks():
    m = box_mask((2, 1, 5, 3), (4, 6))
    assert m.sum() == 6 and m[1, 2] and m[2, 4] and not m[3, 2] and not m[1, 5]
    c = circle_mask((201, 201), (100, 100), 50.0)
    assert c.sum() == pytest.approx(np.pi * 50**2, rel=0.01)
    assert c[100, 150] and not c[100, 151]
    with pytest.raises(RoiError, match="contains no pixel"):
        circle_mask((10, 10), (-20.0, -20.0), 3.0)


def test_mean_and_shapes_box_equals_mask():
    rng = np.random.default_rng(0)
    rad = rng.uniform(1, 2, (8, 9, 3))
    var = rng.uniform(0.01, 0.02, (8, 9, 3))
    box = (2, 1, 7, 6)
    a = reduce_roi(rad, var, box)
    b = reduce_roi(rad, var, box_mask(box, rad.shape))
    assert a.mean.shape == (3,) and a.n_pixels == 25
    np.testing.assert_allclose(a.mean, rad[1:6, 2:7].reshape(-1, 3).mean(axis=0))
    np.testing.assert_allclose(a.mean, b.mean)
    np.testing.assert_allclose(a.std_error_propagated, np.sqrt(var[1:6, 2:7].reshape(-1, 3).sum(axis=0)) / 25)
    np.testing.assert_allclose(a.std_error_spatial, rad[1:6, 2:7].reshape(-1, 3).std(axis=0, ddof=1) / 5)
    mono = reduce_roi(rad[..., 0], var[..., 0], box)
    assert mono.mean.shape == () and float(mono.mean) == pytest.approx(a.mean[0])
    one = reduce_roi(rad[..., 0], var[..., 0], (0, 0, 1, 1))  # one pixel: no spatial estimate
    assert np.isnan(one.std_error_spatial) and float(one.std_error) == pytest.approx(np.sqrt(var[0, 0, 0]))


def test_standard_errors_are_right_over_many_seeds():
    # Uniform ROI under shot and read noise: both estimates describe the scatter of the mean over repeats.
    truth = np.full((20, 20), 4e4)
    rng = np.random.default_rng(1)
    z_prop, z_spat, z_used = [], [], []
    for _ in range(1500):
        rad, var = hdr_like(truth, rng)
        r = reduce_roi(rad, var, (0, 0, 20, 20))
        d = float(r.mean) - 4e4
        z_prop.append(d / float(r.std_error_propagated))
        z_spat.append(d / float(r.std_error_spatial))
        z_used.append(d / float(r.std_error))
        assert r.scatter_ratio == pytest.approx(1.0, abs=0.2)
    for z in (z_prop, z_spat, z_used):
        assert np.std(z) == pytest.approx(1.0, abs=0.06)  # 1500 samples: the std scatters by ~2 %
        assert abs(np.mean(z)) < 0.1


def test_texture_inflates_the_spatial_error_and_max_reports_it():
    rng = np.random.default_rng(2)
    truth = np.random.default_rng(3).uniform(1e4, 6e4, (20, 20))  # fixed texture
    z_prop, ratio = [], []
    for _ in range(600):
        rad, var = hdr_like(truth, rng)
        r = reduce_roi(rad, var, (0, 0, 20, 20))
        assert float(r.std_error) == float(r.std_error_spatial) > float(r.std_error_propagated)
        z_prop.append((float(r.mean) - truth.mean()) / float(r.std_error_propagated))
        ratio.append(float(r.scatter_ratio))
        p = reduce_roi(rad, var, (0, 0, 20, 20), error_model="propagated")
        assert float(p.std_error) == float(r.std_error_propagated)
    assert np.std(z_prop) == pytest.approx(1.0, abs=0.1)  # the propagated one is the noise of the mean
    assert np.median(ratio) > 3


def test_flagged_pixels_are_excluded_and_counted():
    rad = np.full((4, 4, 3), 10.0)
    var = np.ones((4, 4, 3))
    rad[0, 0] = np.nan  # saturated in every frame: no estimate
    rad[1, 1] = 5.0  # clipped value: a lower bound
    flags = np.zeros((4, 4), dtype=np.uint8)
    flags[0, 0] = flags[1, 1] = 1
    r = reduce_roi(rad, var, (0, 0, 4, 4), flags)
    assert r.n_pixels == 16 and r.n_flagged.tolist() == [2, 2, 2] and r.n_used.tolist() == [14, 14, 14]
    np.testing.assert_allclose(r.mean, 10.0)
    assert not r.lower_bound
    with pytest.raises(RoiError, match="2 of 16 ROI pixels are flagged"):
        reduce_roi(rad, var, (0, 0, 4, 4), flags, on_flagged="raise")
    with pytest.raises(RoiError, match="flagged ROI pixels have non-finite"):
        reduce_roi(rad, var, (0, 0, 4, 4), flags, on_flagged="lower_bound")
    rad[0, 0] = 5.0
    var[0, 0] = var[1, 1] = np.inf  # what the HDR merge reports for a pixel saturated in every frame
    lb = reduce_roi(rad, var, (0, 0, 4, 4), flags, on_flagged="lower_bound")
    assert lb.lower_bound and lb.n_used.tolist() == [16, 16, 16]
    np.testing.assert_allclose(lb.mean, (14 * 10 + 2 * 5) / 16)
    np.testing.assert_allclose(lb.std_error_propagated, np.sqrt(14) / 16)  # clipped pixels add no noise term
    with pytest.raises(RoiError, match="2 ROI pixels have non-finite radiance or variance"):
        reduce_roi(rad, var, (0, 0, 4, 4))  # unflagged: never averaged in silently


def test_unknown_variances_allow_the_spatial_error_only():
    rng = np.random.default_rng(6)
    rad = rng.normal(100.0, 2.0, (10, 10))
    var = np.full((10, 10), np.nan)  # the 8-bit path has no per-pixel variance
    r = reduce_roi(rad, var, (0, 0, 10, 10), error_model="spatial")
    assert np.isnan(r.std_error_propagated)
    assert float(r.std_error) == pytest.approx(rad.std(ddof=1) / 10)
    with pytest.raises(RoiError, match="non-finite radiance or variance"):
        reduce_roi(rad, var, (0, 0, 10, 10))


def test_per_channel_flags_and_unflagged_nan():
    rad = np.full((3, 3, 3), 2.0)
    var = np.ones((3, 3, 3))
    flags = np.zeros((3, 3, 3), dtype=bool)
    flags[0, 0, 2] = True
    rad[0, 0, 2] = 1e9
    r = reduce_roi(rad, var, (0, 0, 3, 3), flags)
    assert r.n_flagged.tolist() == [0, 0, 1] and r.n_used.tolist() == [9, 9, 8]
    np.testing.assert_allclose(r.mean, 2.0)
    flags[:, :, 1] = True
    with pytest.raises(RoiError, match=r"all 9 ROI pixels are flagged in channel\(s\) \[1\]"):
        reduce_roi(rad, var, (0, 0, 3, 3), flags)
    rad[2, 2, 0] = np.inf
    with pytest.raises(RoiError, match="1 ROI pixels have non-finite"):
        reduce_roi(rad, var, (0, 0, 3, 3))
    with pytest.raises(RoiError, match="flags have shape"):
        reduce_roi(rad, var, (0, 0, 3, 3), np.zeros((3, 4)))
