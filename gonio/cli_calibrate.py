"""``gonio calibrate``: calibrations of the instrument, one subcommand each (``camera``, ``geometry``).

``gonio calibrate geometry`` mounts a glossy ChArUco board on the stage (the simulated rig renders one; a
real rig asks the operator), captures HDR whole frames at planned poses, and fits the joint zeros, the
sample's tilt and its offset (``rig.alignment``); it writes ``geometry_calibration.json`` (and a figure of
the captures' residuals) into ``--out``. A rig file uses it with ``[geometry] calibration``.

``gonio calibrate camera`` shows the camera a uniform light (the simulated rig's flat source, or on a real
rig an integrating sphere the operator is asked to place), takes a photon-transfer series and a flat-field
series (``rig.run.calibrate``), and writes ``camera_calibration.json``, ``flat_field.npz`` and the photon
transfer curve ``photon_transfer.png`` into ``--out``. A rig file uses them with ``[camera] calibration =
"camera_calibration.json"`` and ``flat_field = "flat_field.npz"``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from gonio.cli_errors import CliError
from gonio.cli_options import add_command, add_quiet_option, add_rig_option, load_rig_option
from gonio.cli_run import EXIT_BAD_INPUT, EXIT_CAMERA, EXIT_HARDWARE, EXIT_OK


def _camera(args: argparse.Namespace) -> int:
    """photon transfer and flat field of the rig's camera: camera_calibration.json

    Shows the camera a uniform light (on a real rig the operator is asked to place an integrating sphere or a diffuser,
    and later to cap the lens), takes flat pairs at equally spaced exposures up to saturation with dark pairs
    (EMVA 1288) and a flat-field series, and fits gain (e-/DN), read noise, dark current, black level, full well and
    linearity with standard errors. Writes camera_calibration.json, flat_field.npz and photon_transfer.png; a rig file
    uses them as [camera] calibration and flat_field.

    Example: gonio calibrate camera --rig examples/rig_simulated_raw.toml --out calib/
    """
    from acquisition.cameras import CameraError
    from acquisition.exposure.spec import CameraTiming
    from acquisition.photon_transfer import PhotonTransferError
    from analysis.camera_plots import plot_photon_transfer
    from rig.run.calibrate import CalibrationSettings, calibrate_camera, write_calibration
    from rig.run.session import instruments

    if args.steps < 6:
        raise CliError(f"--steps {args.steps}: expected at least 6 exposures (photon transfer needs them)")
    if args.flat_frames < 0 or args.flat_frames == 1:
        raise CliError(f"--flat-frames {args.flat_frames}: expected 0 (no flat field) or at least 2")
    rig = load_rig_option(args.rig)
    try:
        settings = CalibrationSettings(steps=args.steps, flat_frames=args.flat_frames)
    except ValueError as exc:  # the settings are the command line's options
        raise CliError(str(exc)) from None
    cam = rig.file.camera
    timing = CameraTiming(cam.min_exposure_s, cam.max_exposure_s, overhead_s=cam.overhead_s)
    say = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    try:
        with instruments(rig) as inst:
            if inst.flat_source is None:
                print(f"gonio: error: the {rig.file.link.kind} backend has no flat-field source", file=sys.stderr)
                return EXIT_BAD_INPUT
            cal = calibrate_camera(inst.camera, inst.flat_source, inst.clock, timing, settings, say)
    except (CameraError, PhotonTransferError, TimeoutError) as exc:
        print(f"gonio: camera calibration failed: {exc}", file=sys.stderr)
        return EXIT_CAMERA
    out = Path(args.out)
    written = write_calibration(cal, settings, out)
    written.append(plot_photon_transfer(cal.ptc, out / "photon_transfer.png", f"{cal.camera_id}: photon transfer"))
    p = cal.ptc
    for key, unit in (("e_per_dn", "e-/DN"), ("read_noise_e", "e-"), ("dark_current_e_per_s", "e-/s"),
                      ("black_level_dn", "DN"), ("full_well_e", "e-")):  # fmt: skip
        est = getattr(p, key)
        print(f"{key:>22} = {est.value:.5g} ± {est.std_error:.2g} {unit}")
    print(f"{'linearity_error':>22} = {p.linearity_error_percent:.3g} %")
    if cal.flat is not None:
        print(f"{'flat field':>22}: vignetting {cal.flat.vignetting:.1%} at the corner, PRNU {cal.flat.prnu_rms:.2%}")
    print(f"{cal.frames} frames, {cal.capture_time_s:.1f} s of capture")
    for note in p.notes:
        print(f"note: {note}")
    for path in written:
        print(f"wrote {path}")
    return EXIT_OK


def geometry_options(args: argparse.Namespace) -> None:
    """Check --squares, --square-mm, --marker-mm, --captures and --alpha up front; CliError names the option."""
    from rig.alignment.poses import MIN_CAPTURES

    def bad(option: str, value: object, expected: str) -> CliError:
        shown = f"{value:g}" if isinstance(value, float) else repr(value)  # as typed: 120, not 120.0
        return CliError(f"{option} {shown}: expected {expected}")

    if not 3 <= args.squares <= 20:
        raise bad("--squares", args.squares, "3 to 20 squares per side of the board")
    if not (math.isfinite(args.square_mm) and 0 < args.square_mm <= 1000):
        raise bad("--square-mm", args.square_mm, "the board's square size in mm, a number > 0 (at most 1000)")
    if not (math.isfinite(args.marker_mm) and 0 < args.marker_mm < args.square_mm):
        raise bad("--marker-mm", args.marker_mm, f"the ArUco marker's size in mm, > 0 and below --square-mm "
                  f"({args.square_mm:g})")  # fmt: skip
    if not MIN_CAPTURES <= args.captures <= 1000:
        raise bad("--captures", args.captures, f"{MIN_CAPTURES} to 1000 captures")
    if not (math.isfinite(args.alpha) and 1e-4 <= args.alpha <= 0.3):
        raise bad("--alpha", args.alpha, "the coat's GGX roughness in [1e-4, 0.3]")


def _geometry(args: argparse.Namespace) -> int:
    """joint zeros, sample tilt and offset from a ChArUco board: geometry_calibration.json

    Mounts a glossy ChArUco board on the stage (on a real rig the operator is asked to), captures HDR whole frames at
    planned poses (a round seeing the board from many directions, then mirror poses that show the lamp's highlight in
    the board's coat), and fits the joints' zero offsets, the sample's tilt on the stage and its offset from the arms'
    axis by least squares, with standard errors and correlations. Writes geometry_calibration.json; a rig file applies
    it with [geometry] calibration = "...".

    Example: gonio calibrate geometry --rig examples/rig_simulated.toml --out calib/
    """
    from acquisition.board import BoardError, ChArUcoBoard
    from rig.alignment.fit import CalibrationError
    from rig.alignment.poses import PoseError
    from rig.alignment.procedure import calibrate_geometry
    from rig.instrument.links.base import LinkError

    geometry_options(args)  # before the rig file: a mistyped option should not wait for a rig to load
    rig = load_rig_option(args.rig)
    say = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    try:
        board = ChArUcoBoard(squares=args.squares, square_mm=args.square_mm, marker_mm=args.marker_mm)
        path = calibrate_geometry(rig, args.out, captures=args.captures, alpha=args.alpha, board=board, log=say)
    except (CalibrationError, PoseError, BoardError) as exc:
        print(f"gonio: geometry calibration failed: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except LinkError as exc:
        print(f"gonio: hardware fault: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    doc = __import__("json").loads(path.read_text())
    for name in ("light_zero_deg", "camera_zero_deg", "tilt_zero_deg", "roll_zero_deg", "yaw_zero_deg",
                 "sample_tilt_deg", "sample_tilt_azimuth_deg"):  # fmt: skip
        if name in doc:
            print(f"{name:>24} = {doc[name]['value']:+.4f} ± {doc[name]['std_error']:.4f}")
    off = doc["sample_offset_mm"]
    print(f"{'sample_offset_mm':>24} = [{', '.join(f'{v:+.3f}' for v in off['value'])}] ± "
          f"[{', '.join(f'{v:.3f}' for v in off['std_error'])}]")  # fmt: skip
    res = doc["residuals"]
    print(f"residuals: corners {res['corners_rms_px']:.3f} px RMS, highlights "
          f"{res['highlights_rms_px'] if res['highlights_rms_px'] is not None else float('nan'):.3f} px RMS, "
          f"chi2/dof {res['reduced_chi2']:.2f}")  # fmt: skip
    for warning in doc["warnings"]:
        print(f"warning: {warning}", file=sys.stderr)
    print(f"wrote {path}")
    return EXIT_OK


def _add_rig_and_out(parser: argparse.ArgumentParser, written: str) -> None:
    """What every calibration takes alike: the rig of --rig, and --out, the folder it writes ``written`` into."""
    add_rig_option(parser)
    parser.add_argument("--out", default=".", help=f"folder for {written} (default: .)")


def add_calibrate_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio calibrate`` and its subcommands."""
    cal = sub.add_parser("calibrate", help="calibrate the instrument (camera: photon transfer; geometry: alignment)",
                         description="Calibrations of the instrument, one subcommand each.")  # fmt: skip
    group = cal.add_subparsers(dest="calibration", required=True, metavar="WHAT")
    camera = add_command(group, "camera", _camera)
    _add_rig_and_out(camera, "camera_calibration.json and the rest")
    camera.add_argument("--steps", type=int, default=32,
                        help="exposures of the photon-transfer series, two flats and two darks each (default 32)")
    camera.add_argument("--flat-frames", type=int, default=16,
                        help="frames of the flat-field series; 0 for none (default 16)")  # fmt: skip
    add_quiet_option(camera, "no progress messages")
    geometry = add_command(group, "geometry", _geometry)
    _add_rig_and_out(geometry, "geometry_calibration.json")
    geometry.add_argument("--captures", type=int, default=30,
                          help="captures: half see the board, half the lamp's mirror (default 30; with 24 a "
                          "glossy sample's fit was 2x a perfect rig's error, with 30 1.0x)")  # fmt: skip
    geometry.add_argument("--alpha", type=float, default=0.01,
                          help="GGX roughness of the board's clear coat (default 0.01, a near-mirror)")  # fmt: skip
    geometry.add_argument("--squares", type=int, default=7, help="board squares per side (default 7)")
    geometry.add_argument("--square-mm", type=float, default=6.0, help="board square size in mm (default 6)")
    geometry.add_argument("--marker-mm", type=float, default=4.5, help="ArUco marker size in mm (default 4.5)")
    add_quiet_option(geometry, "no progress messages")
