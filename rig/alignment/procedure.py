"""``gonio calibrate geometry``: drive the rig through the calibration's poses and fit what it sees.

The rig is opened through its backend (``rig.run.session.instruments``); its board target mounts the
ChArUco board (the simulated rig renders one under a glossy coat, a real one prompts the operator). Each
capture moves the axes, waits in position, reads the joints back, and takes an HDR bracket of whole frames
(exposures chosen from a test frame so the highlight does not clip in the shortest and the print is well
exposed in the longest). The board round is fitted first, the mirror poses are solved with that estimate,
and the fit of all captures is written to ``geometry_calibration.json`` with a residual figure. The axes are
left by the rig's ``on_stop`` policy and the sample is put back, whatever happens.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.board import ChArUcoBoard
from acquisition.frame import Camera, Frame
from acquisition.hdr.merge import HdrImage, merge_linear
from acquisition.noise import SensorNoise
from model.version import gonio_version
from rig.alignment.fit import CalibrationError, Capture, GeometryFit, fit_geometry
from rig.alignment.observe import observe
from rig.alignment.poses import mirror_joints, plan_poses
from rig.instrument.calibration_file import FILE_NAME, sha256_of, write_geometry_calibration
from rig.instrument.camera_model import focal_length_px
from rig.instrument.kinematics import Joints
from rig.run.config.files import RigConfig
from rig.run.config.fitted_for import fitted_for
from rig.run.registry import provided_cameras
from rig.run.session import instruments

Log = Callable[[str], None]
#: Fewest pixels per board square the detector finds reliably on a foreshortened view.
MIN_SQUARE_PX = 20.0


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def square_px(rig: RigConfig, board: ChArUcoBoard, size: tuple[int, int]) -> float:
    """How many pixels one board square spans, seen face on, in a frame of ``size`` (width, height) pixels."""
    g, (w, h) = rig.geometry, size
    view_mm = 2e3 * g.camera_radius_m * math.tan(math.radians(0.5 * g.camera_fov_deg))
    return board.square_mm * min(w, h) / view_mm


def check_square(rig: RigConfig, board: ChArUcoBoard, size: tuple[int, int], *, delivered: bool) -> None:
    """Refuse a frame of ``size`` (width, height) px whose board squares are too small for the detector.

    ``delivered``: the size is what the camera delivered (a real camera's frame size is not a rig file key), not
    the simulated camera's ``resolution``.
    """
    need = square_px(rig, board, size)
    if need >= MIN_SQUARE_PX:
        return
    (w, h), g = size, rig.geometry
    factor = math.ceil(MIN_SQUARE_PX / need)
    seen = (
        f"a {board.square_mm:g} mm board square spans {need:.1f} px (at camera_radius_m {g.camera_radius_m:g}, "
        f"camera_fov_deg {g.camera_fov_deg:g}); geometry calibration needs at least {MIN_SQUARE_PX:g} px"
    )
    if not delivered:
        raise CalibrationError(
            f"{rig.path}: camera.resolution = [{w}, {h}]: {seen}: use a resolution of at least [{w * factor}, "
            f"{h * factor}] (a run renders only its ROI, so a larger resolution costs it little)"
        )
    raise CalibrationError(
        f"{rig.path}: the {rig.file.camera.backend} camera delivered a frame of {w} x {h} px: {seen}: the camera must "
        f"deliver whole frames of at least {w * factor} x {h * factor} px (its full sensor, not a crop or a preview), "
        f"or a board with squares {factor}x larger"
    )


def hdr_frame(camera: Camera, noise: SensorNoise, *, first_s: float = 0.01, max_s: float = 10.0) -> HdrImage:
    """An HDR whole frame: the highlight unclipped in the shortest exposure, the print well exposed in the longest."""
    white = noise.white_level_dn - noise.black_level_dn

    def shoot(t: float) -> Frame:
        camera.set_exposure(t)
        return camera.capture()

    test = shoot(first_s)
    rate = (np.asarray(test.data, dtype=np.float64) - noise.black_level_dn) / test.exposure_s
    lit = rate[rate > 3 * noise.read_noise_e / noise.e_per_dn / test.exposure_s]
    peak = float(rate.max()) if rate.size else 1.0
    if peak >= 0.9 * white / test.exposure_s:  # clipped already: go shorter until it is not
        t = first_s
        while t > 1e-6:
            t /= 8
            frame = shoot(t)
            if float(np.max(np.asarray(frame.data, dtype=np.float64) - noise.black_level_dn)) < 0.9 * white:
                peak = float(np.max(np.asarray(frame.data, dtype=np.float64) - noise.black_level_dn)) / t
                break
    board_rate = float(np.percentile(lit, 75)) if lit.size else peak
    short = min(max(0.4 * white / max(peak, 1e-30), 1e-6), max_s)
    long = min(max(0.5 * white / max(board_rate, 1e-30), short), max_s)
    n = max(1, math.ceil(math.log(long / short, 8))) + 1 if long > short * 1.01 else 1
    exposures = np.geomspace(short, long, n) if n > 1 else np.array([short])
    return merge_linear([shoot(float(t)) for t in exposures], noise)


def _capture(camera: Camera, noise: SensorNoise, link: Any, joints: Joints, board: ChArUcoBoard,
             timeout_s: float, corners: bool = True) -> tuple[Capture, HdrImage]:  # fmt: skip
    link.move_to({k: float(v) for k, v in joints.as_dict().items()})
    held = link.wait_in_position(timeout_s=timeout_s)
    actual = Joints.from_dict({k: float(v) for k, v in held.items() if k in joints.as_dict()})
    hdr = hdr_frame(camera, noise)
    radiance = np.asarray(hdr.radiance, dtype=np.float64)
    seen = observe(radiance, np.asarray(hdr.variance, dtype=np.float64), board, corners=corners)
    return Capture(actual, seen), hdr


def _capture_doc(i: int, kind: str, cap: Capture, hdr: HdrImage, fit: GeometryFit, k: int) -> dict[str, Any]:
    seen = cap.seen
    corners = fit.corner_residuals_px[k]
    hl = fit.highlight_residuals_px[k]
    return {
        "index": i, "kind": kind, "joints_deg": {n: round(float(v), 6) for n, v in cap.joints.as_dict().items()},
        "exposures_s": [float(t) for t in hdr.exposures_s], "corners": len(seen.corner_ids),
        "corners_rms_px": float(np.sqrt(np.mean(corners**2))) if len(corners) else None,
        "highlight_px": [seen.highlight.x, seen.highlight.y] if seen.highlight else None,
        "highlight_std_error_px": seen.highlight.std_error_px if seen.highlight else None,
        "highlight_residual_px": hl.tolist() if hl is not None else None, "note": seen.note,
    }  # fmt: skip


def calibration_document(rig: RigConfig, fit: GeometryFit, board: ChArUcoBoard, alpha: float,
                         captures: Sequence[dict[str, Any]], description: str) -> dict[str, Any]:  # fmt: skip
    """The content of geometry_calibration.json (rig.instrument.calibration_file) for a fit."""
    doc: dict[str, Any] = {}
    for name, (value, se) in fit.quantities().items():
        doc[name] = {"value": value, "std_error": se}
    hls = [h for h in fit.highlight_residuals_px if h is not None]
    seen = [c for c in fit.corner_residuals_px if len(c)]
    corners = np.concatenate(seen) if seen else np.zeros((0, 2))
    rig_path = Path(rig.path)
    doc |= {
        "fitted": list(fit.names),
        "covariance": {"names": list(fit.names), "matrix": fit.covariance.tolist()},
        "correlation": {"names": list(fit.names), "matrix": fit.correlation().tolist()},
        "residuals": {
            "corners_rms_px": float(np.sqrt(np.mean(corners**2))) if corners.size else None,
            "corner_std_error_px": fit.corner_sigma_px,
            "highlights_rms_px": float(np.sqrt(np.mean(np.square(hls)))) if hls else None,
            "highlight_scatter_px": fit.highlight_sigma_px,
            "chi2": fit.chi2, "dof": fit.dof, "reduced_chi2": fit.reduced_chi2,
        },
        "captures": list(captures),
        "board": dataclasses.asdict(board) | {"coat_alpha": alpha, "mounted_by": description},
        "rig": {"path": str(rig_path), "name": rig.file.name, "layout": rig.geometry.layout,
                "sha256": sha256_of(rig_path) if rig_path.is_file() else None, "geometry": fitted_for(rig.file)},
        "gonio_version": gonio_version(),
        "warnings": list(fit.warnings),
    }  # fmt: skip
    return doc


def calibrate_geometry(
    rig: RigConfig,
    out: str | Path,
    *,
    captures: int = 30,
    alpha: float = 0.01,
    board: ChArUcoBoard | None = None,
    move_timeout_s: float | None = None,
    log: Log | None = None,
) -> Path:
    """Run the calibration on ``rig`` and write ``out/geometry_calibration.json``; returns its path."""
    board = board or ChArUcoBoard()
    say = log or _stderr
    rendered = rig.file.camera.backend in provided_cameras()
    if rendered:  # the simulated camera renders [camera] resolution: refused before anything moves
        check_square(rig, board, rig.file.camera.resolution, delivered=False)
    if not 1e-4 <= alpha <= 0.3:
        raise CalibrationError(f"--alpha {alpha!r}: expected the coat's GGX roughness in [1e-4, 0.3]")
    poses = plan_poses(rig.geometry, captures)
    timeout = move_timeout_s or rig.file.link.move_timeout_s
    noise = SensorNoise(**rig.file.camera.noise.model_dump())
    out = Path(out)
    docs: list[dict[str, Any]] = []
    caps: list[Capture] = []
    hdrs: list[HdrImage] = []
    kinds: list[str] = []
    with instruments(rig) as inst:
        if inst.board is None:
            raise CalibrationError(f"{rig.path}: the {rig.file.link.kind} backend cannot mount a calibration board")
        camera = inst.camera
        if hasattr(camera, "full_frame"):
            camera.full_frame = True
        try:
            inst.board.present_board(board, alpha)
            for i, joints in enumerate(poses.board):
                cap, hdr = _capture(camera, noise, inst.link, joints, board, timeout)
                if i == 0 and not rendered:  # a real camera's frame size is what it delivers, not a rig file key
                    check_square(rig, board, _size(hdr), delivered=True)
                caps.append(cap)
                hdrs.append(hdr)
                kinds.append("board")
                say(f"capture {i + 1}/{captures} (board): {len(cap.seen.corner_ids)} corners"
                    + (", highlight" if cap.seen.highlight else ""))  # fmt: skip
            first = fit_geometry(rig.geometry, caps, board.corners_local_m(), _focal(rig, hdrs[0]), _size(hdrs[0]),
                                 fixed=() if any(c.seen.highlight for c in caps) else ("light_zero_deg",))  # fmt: skip
            for j, joints in enumerate(mirror_joints(rig.geometry, poses, first.alignment)):
                cap, hdr = _capture(camera, noise, inst.link, joints, board, timeout, corners=False)
                caps.append(cap)
                hdrs.append(hdr)
                kinds.append("mirror")
                i = len(poses.board) + j
                say(f"capture {i + 1}/{captures} (mirror): "
                    + ("highlight" if cap.seen.highlight else f"no highlight ({cap.seen.note})"))  # fmt: skip
        finally:
            if hasattr(camera, "full_frame"):
                camera.full_frame = False
            inst.board.withdraw_board()
            inst.link.shutdown(keep_torque=rig.file.link.on_stop == "hold")
    mirrors = [c for c, k in zip(caps, kinds, strict=True) if k == "mirror"]
    found = sum(c.seen.highlight is not None for c in mirrors)
    if found < max(2, len(mirrors) // 2):
        notes = sorted({c.seen.note for c in mirrors if c.seen.highlight is None})
        raise CalibrationError(
            f"the lamp's highlight was in view in only {found} of {len(mirrors)} mirror captures ({'; '.join(notes)}): "
            "the rig is misaligned beyond what the planned poses can catch (the light arm's zero, most likely, by "
            "several degrees); check the arms' zeros by eye and run again"
        )
    # A joint rests anywhere within its encoder's count of what it reads: a uniform error, count / sqrt(12).
    joint_std = {a.name: 1.0 / a.units_per_joint_degree / math.sqrt(12.0) for a in rig.axes}
    fit = fit_geometry(rig.geometry, caps, board.corners_local_m(), _focal(rig, hdrs[0]), _size(hdrs[0]),
                       start=first.alignment, alpha=alpha, joint_std_deg=joint_std)  # fmt: skip
    for k, (cap, hdr, kind) in enumerate(zip(caps, hdrs, kinds, strict=True)):
        docs.append(_capture_doc(k, kind, cap, hdr, fit, k))
    doc = calibration_document(rig, fit, board, alpha, docs, inst.board.description)
    doc["sensor_px"] = list(_size(hdrs[0]))  # the camera model's sensor: image mode's tiles must be on the same
    path = write_geometry_calibration(out / FILE_NAME, doc)
    for warning in fit.warnings:
        say(f"warning: {warning}")
    return path


def _focal(rig: RigConfig, hdr: HdrImage) -> float:
    h, w = hdr.radiance.shape[:2]
    return focal_length_px(rig.geometry.camera_fov_deg, w, h)


def _size(hdr: HdrImage) -> tuple[int, int]:
    h, w = hdr.radiance.shape[:2]
    return w, h
