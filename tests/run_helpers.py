"""Rig and sweep tables for runs on the simulated rig, and a camera wrapper that misbehaves on cue."""

from __future__ import annotations

import csv
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.frame import Camera, ExposureSettings, Frame
from model.geometry import degrees_to_vector
from rig.instrument.links.base import MotionLink
from rig.run.backends.hardware import dynamixel_options
from rig.run.config.files import RigConfig, SweepConfig, material_from, parse, rig_config, sweep_config
from rig.run.config.schema import RigFile, SweepFile
from rig.run.storage.store import RunStore
from simulator.grbl_rig import SimulatedGrblRig
from simulator.rig import SimulatedRig

LAMBERT = {"model": "Lambert", "rho_d": 0.5}
GOLD = {"model": "CookTorrance", "alpha": 0.3, "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}


#: What can move the simulated rig's joints (``[simulation] link``): every runner test runs on both.
LINKS = ("dynamixel", "grbl")


def sim_rig(material: dict[str, Any] | None = None, *, on: str = "dynamixel", **tables: Any) -> RigConfig:
    """A simulated-rig config on link ``on`` (``[simulation] link``) with a material and extra tables merged in."""
    simulation = {"material": material or LAMBERT, "seed": 3, "link": on}
    doc: dict[str, Any] = {"simulation": simulation, "reference": {"every": 6}}
    for key, value in tables.items():
        doc[key] = {**doc.get(key, {}), **value}
    return rig_config(parse(doc, RigFile, "test-rig.toml"), "test-rig.toml")


def open_link(sim: SimulatedRig, rig: RigConfig) -> MotionLink:
    """The link a run on ``sim`` uses, opened as the simulated backend opens it."""
    if isinstance(sim, SimulatedGrblRig):
        return sim.open_link()
    return sim.open_link(dynamixel_options(rig))


def left_safe(sim: SimulatedRig) -> bool:
    """Whether a stopped run left the rig safe: servos without torque, or a GRBL at rest with nothing queued."""
    if isinstance(sim, SimulatedGrblRig):
        c = sim.controller
        return c.state in ("Idle", "Alarm") and c.planner_blocks == 0
    assert sim.bus is not None
    torque = [sim.bus.servo(int(a.address)).torque_enabled for a in sim.axes]
    return bool(torque) and not any(torque)


def in_plane_sweep(theta_i: list[float], theta_o: list[float], **capture: Any) -> SweepConfig:
    """An in-plane sweep config with optional [capture] keys."""
    doc: dict[str, Any] = {"sweep": {"kind": "in_plane", "theta_i_deg": theta_i, "theta_o_deg": theta_o}}
    if capture:
        doc["capture"] = capture
    return sweep_config(parse(doc, SweepFile, "test-sweep.toml"), "test-sweep.toml")


def read_rows(path: str | Path) -> list[dict[str, str]]:
    """The rows of a run's table."""
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def truth_and_measured(rows: list[dict[str, str]], rig: RigConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The material's BRDF at the measured angles, the measured BRDF and its standard error, (N, 3) each."""

    def vec(t: str, p: str) -> np.ndarray:
        return degrees_to_vector(np.array([float(r[t]) for r in rows]), np.array([float(r[p]) for r in rows]))

    truth = np.asarray(material_from(rig).eval(vec("theta_i_deg", "phi_i_deg"), vec("theta_o_deg", "phi_o_deg")))
    truth = truth[:, None] * np.ones(3) if truth.ndim == 1 else truth
    got = np.array([[float(r[f"brdf_{c}"]) for c in "rgb"] for r in rows])
    se = np.array([[float(r[f"brdf_se_{c}"]) for c in "rgb"] for r in rows])
    return truth, got, se


class FlakyCamera:
    """Wraps a camera; before the n-th light capture (1-based) runs ``action``, e.g. raising an error."""

    def __init__(self, camera: Camera, actions: dict[int, Callable[[], None]]) -> None:
        self._camera = camera
        self._actions = actions
        self.captures = 0

    @property
    def identity(self) -> str:
        """The wrapped camera's identity."""
        return self._camera.identity

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Pass through."""
        return self._camera.set_exposure(exposure_s, gain)

    def capture(self) -> Frame:
        """Run the action due at this capture, then capture."""
        self.captures += 1
        action = self._actions.get(self.captures)
        if action is not None:
            action()
        return self._camera.capture()

    def capture_dark(self) -> Frame:
        """Pass through."""
        return self._camera.capture_dark()  # type: ignore[attr-defined, no-any-return]

    def close(self) -> None:
        """Pass through."""
        self._camera.close()


def reference_relative_errors(out: str | Path) -> np.ndarray:
    """Relative standard errors (readings, channels) of the reference readings of every round of an adaptive sweep."""
    rounds = sorted(Path(out).glob("round-*"))
    recs = [r for d in rounds for r in RunStore.read(d).records() if r["kind"] == "reference"]
    return np.array([np.asarray(r["reading_std_error"]) / np.asarray(r["reading"]) for r in recs])


def run_outcome(sim: SimulatedRig, rig: RigConfig, sweep: SweepConfig, plan: Any, store: RunStore, camera: Camera,
                link: MotionLink | None = None) -> Any:
    """Run ``plan`` on ``sim`` through ``camera`` (and ``link``, else one opened on it): its summary, or the
    RunStopped that ended it; the store is closed either way."""
    from rig.run.measuring.runner import Runner, RunStopped
    from rig.run.session import capture_settings, options_for, reference_settings

    runner = Runner(plan, store, link or open_link(sim, rig), camera, sim.clock, rig.geometry,
                    capture_settings(rig, sweep), reference=reference_settings(rig), target=sim.reference,
                    options=options_for(rig, sweep, False))  # fmt: skip
    try:
        return runner.run()
    except RunStopped as exc:
        return exc
    finally:
        store.close()


def run_recording_renders(rig: RigConfig, sweep: SweepConfig, out: Path) -> tuple[Any, list[tuple[float, float]]]:
    """Run ``sweep`` on a simulated ``rig`` into ``out``: its outcome and (clock s, camera joint deg) of every render
    (a moving frame renders once per sub-exposure, so these are where the arm truly stood while it was exposed)."""
    from rig.run.session import make_plan, manifest, options_for
    from simulator.from_config import rig_from, spec_from

    plan = make_plan(rig, sweep)
    store = RunStore.create(out, manifest(rig, sweep, plan, options_for(rig, sweep, False)))
    renders: list[tuple[float, float]] = []
    with rig_from(rig, spec=spec_from(rig)) as sim:
        assert sim.camera is not None
        inner = sim._radiance

        def recorded(*args: Any, **kwargs: Any) -> Any:
            renders.append((sim.clock.now(), float(sim.joints_now().as_dict()["camera"])))
            return inner(*args, **kwargs)

        sim._radiance = recorded  # type: ignore[method-assign]
        outcome = run_outcome(sim, rig, sweep, plan, store, sim.camera)
    return outcome, renders
