"""A whole RAW sweep on the simulated rig, end to end: calibrate the camera, then measure gold in colour.

Each frame is rendered by Mitsuba, passed through the hidden sensor model, written as a DNG, read back
through rawpy and its ROI reduced per CFA colour. Run from the repository: ``python examples/raw_sweep.py``.
"""

from __future__ import annotations

import csv
import tempfile
from pathlib import Path

import numpy as np

from acquisition.exposure.spec import CameraTiming
from model.geometry import degrees_to_vector
from rig.run.calibrate import CalibrationSettings, calibrate_camera, write_calibration
from rig.run.config.files import load_rig, material_from, parse, rig_config, sweep_config
from rig.run.config.schema import RigFile, SweepFile
from rig.run.session import instruments, start_run

HERE = Path(__file__).parent


def main() -> None:
    """Calibrate, write the files, measure with them and print the table against the truth."""
    out = Path(tempfile.mkdtemp(prefix="gonio-raw-"))
    rig = load_rig(HERE / "rig_simulated_raw.toml")
    cam = rig.file.camera
    settings = CalibrationSettings()
    with instruments(rig) as inst:
        assert inst.flat_source is not None
        cal = calibrate_camera(inst.camera, inst.flat_source, inst.clock,
                               CameraTiming(cam.min_exposure_s, cam.max_exposure_s), settings)  # fmt: skip
    write_calibration(cal, settings, out)
    p = cal.ptc
    print(f"calibrated: {p.e_per_dn.value:.3f} ± {p.e_per_dn.std_error:.3f} e-/DN, read noise "
          f"{p.read_noise_e.value:.2f} ± {p.read_noise_e.std_error:.2f} e-, vignetting {cal.flat.vignetting:.1%}"
          if cal.flat else "")  # fmt: skip
    table = rig.file.model_dump(mode="json", exclude_none=True)
    table["camera"] = {**table["camera"], "calibration": str(out / "camera_calibration.json"),
                       "flat_field": str(out / "flat_field.npz")}  # fmt: skip
    table["camera"].pop("noise")
    calibrated = rig_config(parse(table, RigFile, rig.path), rig.path)
    doc = {"sweep": {"kind": "in_plane", "theta_i_deg": [30.0], "theta_o_deg": [-60.0, 0.0, 20.0, 30.0, 40.0, 60.0]}}
    sweep = sweep_config(parse(doc, SweepFile, "<raw sweep>"), "<raw sweep>")
    summary = start_run(calibrated, sweep, out / "run", progress=False)
    with open(summary.table, newline="") as fh:
        rows = list(csv.DictReader(fh))

    def col(key: str) -> np.ndarray:
        return np.array([float(r[key]) for r in rows])

    wi = degrees_to_vector(col("theta_i_deg"), col("phi_i_deg"))
    wo = degrees_to_vector(col("theta_o_deg"), col("phi_o_deg"))
    truth = np.asarray(material_from(calibrated).eval(wi, wo))
    got = np.stack([col(f"brdf_{c}") for c in "rgb"], axis=1)
    se = np.stack([col(f"brdf_se_{c}") for c in "rgb"], axis=1)
    print(f"{'theta_o':>8} " + " ".join(f"{c + ' meas':>10} {c + ' true':>8}" for c in "rgb"))
    for r, g, t in zip(rows, got, truth, strict=True):
        print(f"{float(r['theta_o_deg']):8.1f} " + " ".join(f"{a:10.4f} {b:8.4f}" for a, b in zip(g, t, strict=True)))
    print(f"r > g > b at every point: {bool(np.all((got[:, 0] > got[:, 1]) & (got[:, 1] > got[:, 2])))}; "
          f"within 3 standard errors of the truth: {np.mean(np.abs(got - truth) < 3 * se):.0%}; run in {out}")


if __name__ == "__main__":
    main()
