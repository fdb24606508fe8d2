"""The geometry fit on synthetic observations (rig/alignment/fit.py, model.py, observe.py, poses.py): no rendering.

Corners and highlights are predicted by the rig model for a known misalignment, then perturbed by known
noise, so the fit's estimates and its reported errors can be checked against the truth exactly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from acquisition.board import ChArUcoBoard
from rig.alignment.fit import CalibrationError, Capture, fit_geometry
from rig.alignment.model import coat_peak, predict
from rig.alignment.observe import FrameObservation, Highlight, find_highlight, observe
from rig.alignment.poses import PoseError, mirror_joints, plan_poses, wrapped
from rig.instrument.alignment import PARAMETERS, Alignment, aligned_forward, alignment_of, parameters_of
from rig.instrument.camera_model import focal_length_px
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints

BOARD = ChArUcoBoard()
SIZE = (480, 480)
FOCAL = focal_length_px(8.0, *SIZE)
TRUTH = Alignment(light_zero_deg=0.6, camera_zero_deg=-0.4, tilt_zero_deg=0.3, roll_zero_deg=0.8,
                  sample_tilt_deg=0.7, sample_tilt_azimuth_deg=35.0, sample_offset_mm=(1.0, -1.5, 0.8))  # fmt: skip


def _captures(geometry: RigGeometry, truth: Alignment, rng: np.random.Generator, corner_px: float = 0.1,
              highlight_px: float = 0.03, captures: int = 24) -> list[Capture]:  # fmt: skip
    poses = plan_poses(geometry, captures)
    joints = list(poses.board) + list(mirror_joints(geometry, poses, truth))
    corners = BOARD.corners_local_m()
    out = []
    for k, j in enumerate(joints):
        px, hl = predict(geometry, j, truth, corners, FOCAL, SIZE)
        keep = np.all((px > 5) & (px < SIZE[0] - 5), axis=1)
        ids = np.flatnonzero(keep)
        seen_px = px[ids] + rng.normal(0, corner_px, (len(ids), 2))
        highlight = None
        if k >= len(poses.board):
            h = hl + rng.normal(0, highlight_px, 2)
            highlight = Highlight(float(h[0]), float(h[1]), highlight_px, 1.0)
        out.append(Capture(j, FrameObservation(ids.astype(np.int64), seen_px, highlight)))
    return out


def test_the_fit_recovers_a_known_rig_within_its_errors() -> None:
    g = RigGeometry()
    rng = np.random.default_rng(1)
    fit = fit_geometry(g, _captures(g, TRUTH, rng), BOARD.corners_local_m(), FOCAL, SIZE)
    truth = parameters_of(fit.names, TRUTH)
    z = (fit.values - truth) / fit.std_errors()
    assert np.all(np.abs(z) < 4), dict(zip(fit.names, z, strict=True))
    assert fit.reduced_chi2 == pytest.approx(1.0, abs=0.2)
    assert fit.corner_sigma_px == pytest.approx(0.1, rel=0.15)
    q = fit.quantities()
    assert q["sample_tilt_deg"][0] == pytest.approx(0.7, abs=5 * q["sample_tilt_deg"][1])
    assert q["sample_tilt_azimuth_deg"][0] == pytest.approx(35.0, abs=5 * q["sample_tilt_azimuth_deg"][1])
    assert q["sample_offset_mm"][0] == pytest.approx([1.0, -1.5, 0.8], abs=5 * max(q["sample_offset_mm"][1]))


# What each other layout's parameters can hold: an in-plane rig has no stage joints, so its tilt and roll
# zeros are the sample's fixed orientation (a wedge is one of them); a fixed camera has a yaw zero instead.
OTHER_LAYOUTS = {
    "in_plane": Alignment(light_zero_deg=0.6, camera_zero_deg=-0.4, tilt_zero_deg=0.3, roll_zero_deg=0.8,
                          sample_offset_mm=(1.0, -1.5, 0.8)),
    "fixed_camera": Alignment(light_zero_deg=0.6, tilt_zero_deg=0.3, roll_zero_deg=0.8, yaw_zero_deg=0.5,
                              sample_tilt_deg=0.7, sample_tilt_azimuth_deg=35.0, sample_offset_mm=(1.0, -1.5, 0.8)),
}  # fmt: skip


@pytest.mark.parametrize("layout", sorted(OTHER_LAYOUTS))
def test_the_fit_recovers_a_known_rig_of_the_other_layouts(layout: str) -> None:
    g = RigGeometry(layout=layout)
    truth = OTHER_LAYOUTS[layout]
    caps = _captures(g, truth, np.random.default_rng(1), captures=16)
    fit = fit_geometry(g, caps, BOARD.corners_local_m(), FOCAL, SIZE)
    z = (fit.values - parameters_of(fit.names, truth)) / fit.std_errors()
    assert np.all(np.abs(z) < 4), dict(zip(fit.names, z, strict=True))
    assert fit.reduced_chi2 == pytest.approx(1.0, abs=0.2)
    # The light's zero and the camera's (or the yaw's) move the mirror point alike on these rigs: said.
    assert any("light_zero_deg and" in w and "are correlated" in w for w in fit.warnings), fit.warnings


def test_reported_errors_are_honest_over_many_noise_draws() -> None:
    g = RigGeometry()
    zs = []
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        fit = fit_geometry(g, _captures(g, TRUTH, rng, captures=12), BOARD.corners_local_m(), FOCAL, SIZE)
        zs.append((fit.values - parameters_of(fit.names, TRUTH)) / fit.std_errors())
    z = np.asarray(zs)
    # Independent corner noise: the errors are right, or (jackknife) a little conservative, never small.
    assert 0.6 < float(np.sqrt(np.mean(z**2))) < 1.4
    assert np.mean(np.abs(z) < 3) > 0.97


def test_correlated_corner_errors_in_a_frame_widen_the_errors() -> None:
    """A whole frame's corners shifted together (a frame-level error) is what the jackknife is for."""
    g = RigGeometry()
    zs = []
    for seed in range(10):
        rng = np.random.default_rng(200 + seed)
        caps = _captures(g, TRUTH, rng, corner_px=0.02, captures=12)
        for c in caps:
            c.seen.corners_px[:] += rng.normal(0, 0.1, 2)  # one shift per frame
        fit = fit_geometry(g, caps, BOARD.corners_local_m(), FOCAL, SIZE)
        zs.append((fit.values - parameters_of(fit.names, TRUTH)) / fit.std_errors())
    assert float(np.sqrt(np.mean(np.square(zs)))) < 2.0


def test_degenerate_captures_name_the_correlated_pair() -> None:
    g = RigGeometry()
    rng = np.random.default_rng(3)
    caps = [c for c in _captures(g, TRUTH, rng) if c.seen.highlight is not None]
    # The mirror poses at one roll only: the stage's zeros and the wedge cannot be told apart there.
    same = [Capture(caps[0].joints, c.seen) for c in caps[:6]]
    fit = fit_geometry(g, same, BOARD.corners_local_m(), FOCAL, SIZE)
    assert any("are correlated" in w for w in fit.warnings), fit.warnings


def test_no_board_is_a_clear_error() -> None:
    g = RigGeometry()
    empty = [Capture(j, FrameObservation(np.zeros(0, np.int64), np.zeros((0, 2)), None))
             for j in plan_poses(g, 9).board]  # fmt: skip
    with pytest.raises(CalibrationError, match="board was found in no capture"):
        fit_geometry(g, empty, BOARD.corners_local_m(), FOCAL, SIZE)


def test_parameters_and_alignments_round_trip_for_every_layout() -> None:
    for layout, names in PARAMETERS.items():
        a = Alignment(light_zero_deg=0.1, camera_zero_deg=0.2 if layout != "fixed_camera" else 0.0, tilt_zero_deg=0.3,
                      roll_zero_deg=0.4, yaw_zero_deg=0.5 if layout == "fixed_camera" else 0.0,
                      sample_tilt_deg=0.6 if layout != "in_plane" else 0.0, sample_tilt_azimuth_deg=70.0,
                      sample_offset_mm=(1.0, 2.0, 3.0))  # fmt: skip
        back = alignment_of(names, parameters_of(names, a))
        if layout == "in_plane":
            back = Alignment(**{**back.__dict__, "sample_tilt_azimuth_deg": 70.0})
        assert back.sample_tilt_deg == pytest.approx(a.sample_tilt_deg)
        assert back.light_zero_deg == pytest.approx(a.light_zero_deg)


@pytest.mark.parametrize("captures", [8, 24, 30, 40, 60])
def test_every_board_capture_has_angles_of_its_own(captures: int) -> None:
    # A servo rests the same way at the same goal: captures that repeat an angle share its error, which then
    # averages out over none of them (the camera at 3 angles over 15 captures put its zero 3 errors off).
    count = 360.0 / 4096
    board = plan_poses(RigGeometry(), captures).board
    for name in ("light", "camera", "tilt", "roll"):
        goals = [round(getattr(j, name) / count) for j in board]
        assert len(set(goals)) == len(goals), (name, goals)


def test_too_few_captures_are_refused() -> None:
    with pytest.raises(PoseError, match="at least 8 captures"):
        plan_poses(RigGeometry(), 5)


@pytest.mark.parametrize("captures", [30, 40])
@pytest.mark.parametrize("roll_zero_deg", [-15.0, 15.0])
def test_mirror_rolls_past_a_half_turn_are_wrapped_into_the_rolls_limits(captures: int, roll_zero_deg: float) -> None:
    # The mirror poses spread the roll to within 180 / n of +-180 deg: a stage whose roll zero is 15 deg off puts the
    # first or last one past a half turn, which is the same pose a whole turn back (it was refused as beyond limits).
    g = RigGeometry()
    poses = plan_poses(g, captures)
    estimate = Alignment(roll_zero_deg=roll_zero_deg, light_zero_deg=0.5, sample_tilt_deg=0.6)
    joints = mirror_joints(g, poses, estimate)
    rolls = np.array([j.roll for j in joints])
    assert np.all((rolls >= -180.0) & (rolls <= 180.0)), rolls
    # The wrapped roll is the solver's own (the drawn roll shifted by the zero) a whole turn away.
    edge = 0 if roll_zero_deg < 0 else -1
    drawn = -(180.0 - 360.0 * (0.5 if edge == 0 else len(rolls) - 0.5) / len(rolls))
    assert abs(drawn + roll_zero_deg) > 180.0
    assert rolls[edge] == pytest.approx(drawn + roll_zero_deg - math.copysign(360.0, roll_zero_deg), abs=0.5)
    for j, wi, wo in zip(joints, poses.mirror_wi, poses.mirror_wo, strict=True):
        d = aligned_forward(g, j, estimate)
        assert np.allclose(d.wi, wi, atol=1e-8) and np.allclose(d.wo, wo, atol=1e-8)


def test_a_joint_angle_is_wrapped_by_whole_turns_only_where_its_limits_allow() -> None:
    assert wrapped(-307.0, -180.0, 180.0) == pytest.approx(53.0)
    assert wrapped(187.74, -180.0, 180.0) == pytest.approx(-172.26)
    assert wrapped(-300.0, -90.0, 90.0) == pytest.approx(60.0)
    assert wrapped(200.0, -90.0, 90.0) == 200.0  # no whole turn brings it inside: left for the limit check to name
    assert wrapped(370.0, -720.0, 720.0) == 370.0  # inside already: the nearest turn is none
    assert wrapped(-170.0, -180.0, 180.0) == -170.0


def test_the_highlight_peak_is_found_to_a_fraction_of_a_pixel() -> None:
    rng = np.random.default_rng(4)
    y, x = np.mgrid[0:60, 0:80] + 0.5
    spot = 500.0 * np.exp(-((x - 41.3) ** 2 + (y - 27.8) ** 2) / (2 * 3.0**2)) + 5.0
    noisy = rng.poisson(spot * 20) / 20.0
    found, why = find_highlight(noisy, spot / 20.0)
    assert found is not None, why
    assert (found.x, found.y) == (pytest.approx(41.3, abs=0.05), pytest.approx(27.8, abs=0.05))
    assert 0 < found.std_error_px < 0.05
    edge = 500.0 * np.exp(-((x - 1.0) ** 2 + (y - 27.8) ** 2) / (2 * 3.0**2)) + 5.0
    assert find_highlight(edge, edge)[1].startswith("the highlight touches the frame's edge")
    assert find_highlight(np.full((20, 20), 5.0), np.ones((20, 20)))[0] is None


def _board_frame(stray: float, spot: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A board pose's frame (counts/s) and variance: the print under a beam falling 5 % to its edge, set in
    surroundings that only stray light reaches, and a lamp's highlight of ``spot`` times the white at (300, 290)."""
    printed = BOARD.image(6.0).astype(np.float64) / 255.0
    frame = np.full((600, 600), stray)
    y, x = np.mgrid[0:600, 0:600] + 0.5
    dome = 1.0 - 0.05 * ((x - 300.0) ** 2 + (y - 300.0) ** 2) / 300.0**2
    n = printed.shape[0]
    o = (600 - n) // 2
    frame[o : o + n, o : o + n] += 1e5 * (0.04 + 0.86 * printed) * dome[o : o + n, o : o + n]
    frame += spot * 1e5 * np.exp(-((x - 300.3) ** 2 + (y - 290.6) ** 2) / (2 * 4.0**2))
    return frame, frame / 4.0 + 9.0


@pytest.mark.parametrize("stray", [0.0, 20.0])
def test_a_board_pose_without_the_lamps_highlight_keeps_its_corners(stray: float) -> None:
    # Surroundings lit by stray light (examples/rig_misaligned.toml: 20 counts/s) made the whole frame's median
    # thousands of times below the print: the white print's domed brightest pixel passed as a highlight, whose
    # "glare" then took every corner (7 of 15 board captures found none).
    frame, var = _board_frame(stray)
    seen = observe(frame, var, BOARD)
    assert seen.highlight is None and "below" in seen.note
    assert len(seen.corner_ids) >= 20
    lit, lit_var = _board_frame(stray, spot=100.0)
    found = observe(lit, lit_var, BOARD, corners=False).highlight
    assert found is not None and (found.x, found.y) == (pytest.approx(300.3, abs=0.05), pytest.approx(290.6, abs=0.05))


def test_the_coats_peak_leans_off_the_mirror_point_by_a_fraction_of_a_pixel() -> None:
    g = RigGeometry()
    poses = plan_poses(g, 12)
    j = mirror_joints(g, poses, Alignment())[0]
    _, mirror = predict(g, j, Alignment(), np.zeros((0, 3)), FOCAL, SIZE)
    peak = coat_peak(g, j, Alignment(), FOCAL, SIZE, alpha=0.01)
    shift = float(np.hypot(*(peak - mirror)))
    assert 1e-3 < shift < 1.0
    rough = float(np.hypot(*(coat_peak(g, j, Alignment(), FOCAL, SIZE, alpha=0.05) - mirror)))
    assert rough > shift  # the slopes pull harder on a wider lobe
    assert math.isfinite(rough)


def _shaken(captures: list[Capture], px: float) -> list[Capture]:
    """The captures with their highlights moved +-``px`` in x, alternately (as a rough coat's lean can)."""
    out = []
    for k, c in enumerate(captures):
        h = c.seen.highlight
        if h is not None:
            h = Highlight(h.x + px * (-1) ** k, h.y, h.std_error_px, h.peak)
        out.append(Capture(c.joints, FrameObservation(c.seen.corner_ids, c.seen.corners_px, h)))
    return out


def test_residuals_beyond_the_noise_are_warned_of() -> None:
    """A scatter the model lacks (highlights 1.5 px off, joints exact) widens the errors and is said, not hidden."""
    g = RigGeometry()
    caps = _shaken(_captures(g, TRUTH, np.random.default_rng(5), captures=12), 1.5)
    fit = fit_geometry(g, caps, BOARD.corners_local_m(), FOCAL, SIZE)
    assert fit.highlight_sigma_px == pytest.approx(1.5, rel=0.3)
    assert any("highlights scatter" in w and "errors may understate" in w for w in fit.warnings), fit.warnings
    q = fit.quantities()
    assert abs(q["light_zero_deg"][0] - TRUTH.light_zero_deg) < 3 * q["light_zero_deg"][1]
    clean = fit_geometry(g, _captures(g, TRUTH, np.random.default_rng(5), captures=12), BOARD.corners_local_m(),
                         FOCAL, SIZE)  # fmt: skip
    assert not any("their noise" in w or "highlights scatter" in w for w in clean.warnings), clean.warnings
    assert clean.highlight_sigma_px < 0.05
    # What the joints' encoder counts move the highlights by is expected (a servo rests anywhere within its count).
    count = 360.0 / 4096
    jittered = fit_geometry(g, _shaken(_captures(g, TRUTH, np.random.default_rng(5), captures=12), 1.0),
                            BOARD.corners_local_m(), FOCAL, SIZE,
                            joint_std_deg=dict.fromkeys(g.joint_names, count / math.sqrt(12)))  # fmt: skip
    assert not any("highlights scatter" in w for w in jittered.warnings), jittered.warnings


def test_highlights_scattering_as_the_joints_rest_within_their_counts_have_honest_errors() -> None:
    # Each joint rests anywhere within its encoder's count (joint_settle_ticks = 1): the highlights scatter by 1-2
    # px about the fit, 500 times their peak fits' errors. Counted alone, those made chi2/dof 137 on a rendered rig
    # (examples/rig_misaligned.toml), a warning that the model does not explain the captures, and errors scaled up
    # by its root for every quantity alike, the board's too.
    g = RigGeometry()
    count = 360.0 / 4096
    z = []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        poses = plan_poses(g, 16)
        caps = []
        for k, read in enumerate([*poses.board, *mirror_joints(g, poses, TRUTH)]):
            true = Joints.from_dict({n: v + count * rng.uniform(-0.5, 0.5) for n, v in read.as_dict().items()})
            px, hl = predict(g, true, TRUTH, BOARD.corners_local_m(), FOCAL, SIZE)
            ids = np.flatnonzero(np.all((px > 5) & (px < SIZE[0] - 5), axis=1)) if k < len(poses.board) else []
            seen_px = px[ids] + rng.normal(0, 0.1, (len(ids), 2))
            h = hl + rng.normal(0, 0.003, 2)
            highlight = Highlight(float(h[0]), float(h[1]), 0.003, 1.0) if k >= len(poses.board) else None
            caps.append(Capture(read, FrameObservation(np.asarray(ids, dtype=np.int64), seen_px, highlight)))
        fit = fit_geometry(g, caps, BOARD.corners_local_m(), FOCAL, SIZE,
                           joint_std_deg=dict.fromkeys(g.joint_names, count / math.sqrt(12)))  # fmt: skip
        assert 0.5 < fit.highlight_sigma_px < 3.0
        assert fit.reduced_chi2 < 1.5 and not fit.warnings, fit.warnings
        q = fit.quantities()
        z.append([(q[n][0] - getattr(TRUTH, n)) / q[n][1] for n in ("light_zero_deg", "camera_zero_deg")])
    assert float(np.sqrt(np.mean(np.square(z)))) < 1.6, z
