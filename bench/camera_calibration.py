"""Camera calibration: photon transfer recovering hidden sensors, and the dial of frames against accuracy.

Sensors: ``SensorTruth.random(seed)`` for 24 seeds (12 to 16 bits, 0.5 to 8 e-/DN, read noise 0.7 to 4 counts,
dark current 0.05 to 50 e-/s, full well half to twice the ADC's range, vignetting up to 40 %, PRNU up to
2 %, non-linearity up to 2 % at full well), each a 64 x 48 RAW sensor behind the simulated flat-field
source (a warm light: blue gets 60 % of red), on simulated time. The procedure is ``gonio calibrate
camera``'s (``rig.run.calibrate.calibrate_camera``). For each setting of the dial (exposures in the series;
two flats and two darks each) it reports: how often the truth lies within 3 reported standard errors
(gain, read noise), the RMS of (fit - truth) / SE (about 1 when the errors are honest), the median relative
standard error, and the capture time the calibration costs (s of camera time, frames and metering
included). The flat field (16 frames) is judged by the residual non-uniformity it leaves on a new flat
frame, against that frame's photon noise.

Anchors measured in the same run: the accuracy of the 64-step series (each setting's gain error is given
as a ratio to it), and the exposure time alone of the frames (each capture time as a ratio to it: the rest
is the saturation search and the camera's overhead, none here).

Run: ``.venv/bin/python -m bench.camera_calibration [--sensors N]``; prints the tables and rewrites the
``camera_calibration`` section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime

import numpy as np

from acquisition.exposure.spec import CameraTiming
from acquisition.hdr.merge import merge_linear
from bench._common import BENCHMARKS_MD, format_table, machine_description, markdown_table, write_section
from rig.instrument.clock import ManualClock
from rig.run.calibrate import CalibrationSettings, calibrate_camera
from simulator.camera.pixels import SensorTruth
from simulator.camera.simulated import CameraOptics, SimulatedCamera
from simulator.camera.view import SimulatedFlatSource

RESOLUTION = (64, 48)
STEPS = (8, 16, 32, 64)


def _camera(truth: SensorTruth, seed: int) -> tuple[SimulatedCamera, SimulatedFlatSource, ManualClock]:
    clock = ManualClock()
    optics = CameraOptics()
    source = SimulatedFlatSource(RESOLUTION, truth.noise, optics)
    camera = SimulatedCamera(source.patch, noise=truth.noise, optics=optics, kind="raw", clock=clock, seed=seed,
                             response=truth.response, min_exposure_s=1e-5, max_exposure_s=30.0)  # fmt: skip
    return camera, source, clock


def _flat_residual(truth: SensorTruth, seed: int, flat: object) -> float:
    """Residual non-uniformity after the flat field over the photon noise, on a new flat frame."""
    camera, source, _ = _camera(truth, seed + 10_000)
    source.illuminate()
    t = 0.5 * 0.05
    camera.set_exposure(t)
    light = [camera.capture()]
    source.darken()
    darks = [camera.capture() for _ in range(4)]
    hdr = merge_linear(light, truth.noise, darks={light[0].exposure_s: darks})
    corrected = flat.apply(hdr)  # type: ignore[attr-defined]
    out = []
    pattern = light[0].cfa_pattern or "RGGB"
    for i, letter in enumerate(pattern):
        if letter == "G" and i != pattern.index("G"):
            continue
        site = (slice(i // 2, None, 2), slice(i % 2, None, 2))
        rad, var = corrected.radiance[site], corrected.variance[site]
        rel = rad / np.median(rad)
        photon = np.sqrt(np.median(var)) / np.median(rad)
        out.append(np.sqrt(max(np.var(rel) - photon**2, 0.0)) / photon)
    return float(max(out))


def run(sensors: int) -> tuple[list[list[str]], list[list[str]], dict[str, float]]:
    results: dict[int, list[tuple[float, ...]]] = {s: [] for s in STEPS}
    residuals = []
    for seed in range(sensors):
        truth = SensorTruth.random(seed)
        for steps in STEPS:
            camera, source, clock = _camera(truth, seed)
            settings = CalibrationSettings(steps=steps, flat_frames=16 if steps == 32 else 0)
            cal = calibrate_camera(camera, source, clock, CameraTiming(1e-5, 30.0), settings)
            p = cal.ptc
            exposure_only = float(sum(pt.exposure_s for pt in p.points if pt.plane == "R") * 4)
            results[steps].append((
                (p.e_per_dn.value - truth.noise.e_per_dn) / p.e_per_dn.std_error,
                (p.read_noise_e.value - truth.noise.read_noise_e) / p.read_noise_e.std_error,
                p.e_per_dn.std_error / p.e_per_dn.value, p.read_noise_e.std_error / p.read_noise_e.value,
                cal.capture_time_s, cal.frames, exposure_only,
                abs(p.e_per_dn.value / truth.noise.e_per_dn - 1),
            ))  # fmt: skip
            if cal.flat is not None:
                residuals.append(_flat_residual(truth, seed, cal.flat))
    anchor = float(np.sqrt(np.mean(np.array(results[64])[:, 7] ** 2)))
    rows, rows_md = [], []
    for steps in STEPS:
        a = np.array(results[steps])
        gain_err = float(np.sqrt(np.mean(a[:, 7] ** 2)))
        row = [str(steps), f"{np.mean(np.abs(a[:, 0]) < 3):.0%}", f"{np.mean(np.abs(a[:, 1]) < 3):.0%}",
               f"{np.sqrt(np.mean(a[:, 0] ** 2)):.2f}", f"{np.sqrt(np.mean(a[:, 1] ** 2)):.2f}",
               f"{np.median(a[:, 2]):.2%}", f"{np.median(a[:, 3]):.2%}", f"{gain_err:.2%}", f"{gain_err / anchor:.2f}",
               f"{np.mean(a[:, 4]):.2f}", f"{np.mean(a[:, 5]):.0f}", f"{np.mean(a[:, 4] / a[:, 6]):.2f}"]  # fmt: skip
        rows.append(row)
        rows_md.append(row)
    summary = {"flat_residual_max": float(np.max(residuals)), "flat_residual_median": float(np.median(residuals)),
               "flat_sensors": float(len(residuals))}  # fmt: skip
    return rows, rows_md, summary


HEADERS = ["steps", "gain in 3 SE", "read in 3 SE", "RMS z gain", "RMS z read", "SE gain", "SE read",
           "RMS gain error", "ratio to 64 steps", "capture s", "frames", "ratio to exposure"]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sensors", type=int, default=24)
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/benchmarks.md alone")
    args = parser.parse_args()
    machine = machine_description()
    rows, rows_md, summary = run(args.sensors)
    print(f"camera calibration over {args.sensors} random sensors ({machine})")
    print(format_table(HEADERS, rows))
    print(f"flat field (16 frames, 32-step runs): residual non-uniformity / photon noise of a new flat frame: median "
          f"{summary['flat_residual_median']:.2f}, max {summary['flat_residual_max']:.2f} over "
          f"{summary['flat_sensors']:.0f} sensors")  # fmt: skip
    if args.no_write:
        return
    today = datetime.date.today().isoformat()
    body = "\n".join([
        "## Camera calibration (`bench/camera_calibration.py`)", "",
        f"Measured {today} on {machine} (shared machine, other work running). Photon transfer "
        f"(`gonio calibrate camera`'s procedure) on {args.sensors} random hidden sensors "
        "(`SensorTruth.random`: 12-16 bits, 0.5-8 e-/DN, read noise 0.7-4 counts, vignetting to 40 %, PRNU to 2 %, "
        "non-linearity to 2 %), 64 x 48 RAW, simulated flat source and time. Per setting of the dial (exposures "
        "of the series, two flats and two darks each): the share of sensors whose gain and read noise lie within "
        "3 reported standard errors, the RMS of (fit - truth) / SE (about 1: the errors are honest), the median "
        "relative standard error, the RMS relative gain error and its ratio to the 64-step series (the anchor), "
        "and the capture time a calibration costs (camera seconds, saturation search included) with its ratio "
        "to the frames' exposure time alone.", "",
        markdown_table(HEADERS, rows_md), "",
        f"Flat field (16 frames at half saturation, from the 32-step runs): the residual non-uniformity it leaves "
        f"on a new flat frame is {summary['flat_residual_median']:.2f} (median) and {summary['flat_residual_max']:.2f} "
        f"(max) of that frame's photon noise over {summary['flat_sensors']:.0f} sensors. "
        "Command: `.venv/bin/python -m bench.camera_calibration`.",
    ])  # fmt: skip
    write_section(BENCHMARKS_MD, "camera_calibration", body)


if __name__ == "__main__":
    main()
