"""Sweep generators: shapes, order, normalisation and dedupe, signs, half/difference round trips, isotropy."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from model.geometry import degrees_to_vector, from_half_diff
from rig.run.config import sweeps

theta = st.floats(0.0, 90.0)
phi = st.floats(-720.0, 720.0)
row = st.tuples(theta, phi, theta, phi)


def angle_between(p):
    """Angle in degrees between wi and wo of rows (N, 4) in degrees."""
    p = np.asarray(p, dtype=float)
    a, b = degrees_to_vector(p[:, 0], p[:, 1]), degrees_to_vector(p[:, 2], p[:, 3])
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def check_rows(p):
    assert p.dtype == np.float64 and p.ndim == 2 and p.shape[1] == 4
    assert np.all((p[:, [1, 3]] >= 0.0) & (p[:, [1, 3]] < 360.0))
    assert np.all((p[:, [0, 2]] >= 0.0) & (p[:, [0, 2]] <= 90.0))
    assert np.all(p[p[:, 0] == 0.0, 1] == 0.0) and np.all(p[p[:, 2] == 0.0, 3] == 0.0)


# --- grid ---------------------------------------------------------------------------------------------


def test_grid_shape_and_order():
    p = sweeps.grid([10, 30], [20, 40, 60], [90, 180])
    check_rows(p)
    assert p.shape == (12, 4)
    assert p[:3].tolist() == [[10, 0, 20, 90], [10, 0, 20, 180], [10, 0, 40, 90]]
    assert p[-1].tolist() == [30, 0, 60, 180]


def test_grid_merges_the_pole_azimuths():
    # At theta = 0 every azimuth is the same direction: one row per theta_o, not one per phi.
    p = sweeps.grid([0, 30], [0, 30], phi_o_deg=[0, 90, 180, 270], phi_i_deg=[0, 90])
    check_rows(p)
    assert len(p) == len(np.unique(p, axis=0))
    assert len(p[p[:, 0] == 0]) == 1 + 4  # theta_o = 0 once, theta_o = 30 at 4 azimuths
    assert len(p[p[:, 0] == 30]) == 2 * (1 + 4)


def test_grid_rejects_bad_angles_by_name():
    with pytest.raises(ValueError, match=r"theta_i_deg\[1\] = -5"):
        sweeps.grid([10, -5], [30])
    with pytest.raises(ValueError, match=r"phi_o_deg\[0\] = nan"):
        sweeps.grid([10], [30], [float("nan")])


def test_dedupe_tolerance_and_wrap():
    p = sweeps.explicit([[30, 0, 30, 180], [30, 360, 30, 180 + 1e-10], [30, -1e-12, 30, -180], [30, 1e-6, 30, 180]])
    check_rows(p)
    assert p.tolist() == [[30, 0, 30, 180], [30, 1e-6, 30, 180]]


@given(st.lists(row, min_size=1, max_size=20), st.randoms(use_true_random=False))
def test_dedupe_removes_near_copies_and_keeps_first(rows, rnd):
    base = sweeps.explicit(rows)
    noisy = [list(r) for r in base] + [[v + rnd.uniform(-4e-10, 4e-10) * (0 < v < 90) for v in r] for r in base]
    noisy = [[r[0], r[1] + 360.0 * rnd.choice([-1, 0, 1]), r[2], r[3]] for r in noisy]
    again = sweeps.explicit(noisy)
    assert len(again) == len(base)
    np.testing.assert_allclose(again, base, atol=1e-6)


# --- in-plane -----------------------------------------------------------------------------------------


def test_in_plane_signs():
    p = sweeps.in_plane([30], [-60, 0, 45])
    assert p.tolist() == [[30, 0, 60, 0], [30, 0, 0, 0], [30, 0, 45, 180]]
    q = sweeps.in_plane([30], [-60, 45], phi_i_deg=90.0)
    assert q.tolist() == [[30, 90, 60, 90], [30, 90, 45, 270]]


def test_in_plane_mirror_is_at_positive_theta_o():
    p = sweeps.in_plane([40], [40])
    wi, wo = degrees_to_vector(p[0, 0], p[0, 1]), degrees_to_vector(p[0, 2], p[0, 3])
    np.testing.assert_allclose(wo, 2 * wi[2] * np.array([0, 0, 1.0]) - wi, atol=1e-12)


def test_in_plane_rejects_out_of_range():
    with pytest.raises(ValueError, match=r"theta_o_deg\[1\] = -95"):
        sweeps.in_plane([30], [10, -95])


# --- Rusinkiewicz -------------------------------------------------------------------------------------


def test_rusinkiewicz_known_pairs():
    # theta_d = 0: wi = wo = h. theta_h = 0: wi and wo mirror each other about the normal.
    p = sweeps.rusinkiewicz([30], [0], [0, 90], [45])
    np.testing.assert_allclose(p, [[30, 45, 30, 45]], atol=1e-12)
    q = sweeps.rusinkiewicz([0], [40], [90])
    np.testing.assert_allclose(q, [[40, 90, 40, 270]], atol=1e-12)


def test_rusinkiewicz_accounts_for_every_combination():
    s = sweeps.rusinkiewicz_sweep([0, 20, 45, 70, 89], [0, 30, 60, 89], [0, 45, 90, 180, 270], [0, 90])
    check_rows(s.points)
    assert s.combinations == 5 * 4 * 5 * 2
    assert s.below_horizon_count > 0 and s.duplicate_count > 0
    assert len(s.points) + s.below_horizon_count + s.duplicate_count == s.combinations
    dropped = sweeps.half_diff_to_directions(*s.below_horizon.T)
    assert np.all(np.maximum(dropped[:, 0], dropped[:, 2]) > 90.0)
    np.testing.assert_array_equal(sweeps.rusinkiewicz([0, 20, 45, 70, 89], [0, 30, 60, 89], [0, 45, 90, 180, 270],
                                                      [0, 90]), s.points)  # fmt: skip


@given(st.floats(0.0, 89.0), st.floats(0.0, 89.0), phi, phi)
def test_half_diff_round_trip_directions(th, td, pd, ph):
    rows = sweeps.half_diff_to_directions(th, td, pd, ph)
    wi, wo = from_half_diff(*np.radians([th, ph, td, pd]))
    np.testing.assert_allclose(degrees_to_vector(rows[0], rows[1]), wi, atol=1e-12)
    np.testing.assert_allclose(degrees_to_vector(rows[2], rows[3]), wo, atol=1e-12)
    back = sweeps.half_diff_to_directions(*sweeps.directions_to_half_diff(rows))
    np.testing.assert_allclose(degrees_to_vector(back[0], back[1]), wi, atol=1e-9)
    np.testing.assert_allclose(degrees_to_vector(back[2], back[3]), wo, atol=1e-9)


@given(st.floats(1.0, 89.0), st.floats(1.0, 89.0), phi, phi)
def test_half_diff_round_trip_angles(th, td, pd, ph):
    hd = sweeps.directions_to_half_diff(sweeps.half_diff_to_directions(th, td, pd, ph))
    np.testing.assert_allclose(hd[:2], [th, td], atol=1e-9)
    for got, want in ((hd[2], pd), (hd[3], ph)):
        assert abs((got - want + 180.0) % 360.0 - 180.0) < 1e-8


@settings(deadline=None)  # a loaded CI machine must not fail a test on time
@given(st.lists(st.tuples(st.floats(0, 85), st.floats(0, 85), phi, phi), min_size=1, max_size=10))
def test_rusinkiewicz_points_round_trip(combos):
    th, td, pd, ph = (sorted({c[k] for c in combos}) for k in range(4))
    s = sweeps.rusinkiewicz_sweep(th, td, pd, ph)
    hd = sweeps.directions_to_half_diff(s.points)
    back = sweeps.half_diff_to_directions(*hd.T)
    for a, b in ((0, 1), (2, 3)):
        np.testing.assert_allclose(
            degrees_to_vector(back[:, a], back[:, b]), degrees_to_vector(s.points[:, a], s.points[:, b]), atol=1e-9
        )


# --- explicit -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("points", "pattern"),
    [
        ([[0, 0, 10, 0], [10, 0, 95, 0]], r"row 1: theta_o = 95"),
        ([[0, 0, 10, 0], [10, 0, 20, 0], [-1, 0, 0, 0]], r"row 2: theta_i = -1"),
        ([[0, 0, 10, 0], [10, float("inf"), 20, 0]], r"row 1: phi_i = inf"),
        ([[0, 0, 10, 0], [10, 0, 20]], r"row 1: 3 values"),
        ([[0, 0, 10, 0], [10, 0, "x", 0]], r"row 1: theta_o = 'x'"),
        ([5, 6, 7, 8], r"row 0: 5 is not a sequence"),
    ],
)
def test_explicit_errors_name_row_and_value(points, pattern):
    with pytest.raises(ValueError, match=pattern):
        sweeps.explicit(points)


def test_explicit_keeps_order_and_accepts_empty():
    p = sweeps.explicit([[60, 10, 20, 200], [10, 0, 20, 0], [60, 370, 20, -160]])
    assert p.tolist() == [[60, 10, 20, 200], [10, 0, 20, 0]]
    assert sweeps.explicit([]).shape == (0, 4)


# --- isotropic ----------------------------------------------------------------------------------------


def test_isotropic_examples():
    p = sweeps.isotropic(np.array([[30, 10, 40, 300], [30, 0, 40, 70], [0, 0, 20, 33], [30, 50, 0, 0]]))
    assert p.tolist() == [[30, 0, 40, 70], [0, 0, 20, 180], [30, 0, 0, 0]]


@given(st.lists(row, min_size=1, max_size=30))
def test_isotropic_invariants(rows):
    src = sweeps.explicit(rows)
    out = sweeps.isotropic(src)
    check_rows(out)
    assert len(out) <= len(src)
    assert np.all(out[:, 1] == 0.0) and np.all(out[:, 3] <= 180.0)
    for r in src:
        one = sweeps.isotropic(r[None, :])
        assert one.shape == (1, 4)
        np.testing.assert_allclose(one[0, [0, 2]], r[[0, 2]], atol=1e-12)
        np.testing.assert_allclose(angle_between(one), angle_between(r[None, :]), atol=1e-7)
        # The reduced row is in the output (up to the dedupe tolerance).
        assert np.min(np.max(np.abs(out - one), axis=1)) <= 2e-9


def test_isotropic_reduces_a_full_azimuth_grid():
    full = sweeps.grid([30], [45], phi_o_deg=np.arange(0, 360, 30), phi_i_deg=np.arange(0, 360, 30))
    out = sweeps.isotropic(full)
    assert len(full) == 144
    np.testing.assert_allclose(out[:, 3], np.arange(0, 181, 30))


@given(theta, phi, theta, phi)
def test_isotropic_is_idempotent(ti, pi, to, po):
    assume(ti > 1e-6 and to > 1e-6)
    once = sweeps.isotropic(np.array([[ti, pi, to, po]]))
    np.testing.assert_allclose(sweeps.isotropic(once), once, atol=1e-9)
