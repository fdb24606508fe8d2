"""Fitting the ladder in two processes (``fit_ladder(..., jobs=2)``, as ``gonio analyze`` does): the same candidates,
warnings, angular variances and log lines as one process gives, both processes really fitting, and a helper that
dies leaving its candidates to this process.

Each check runs in a fresh interpreter (``python -m tests.analysis.test_ladder NAME``): a fork is taken only where it
is safe, and a test process that has loaded Mitsuba (another test's export) or started threads is not such a place.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import analysis.ladder as ladder_mod
from analysis.ladder import fit_ladder
from model import CookTorrance
from model.fit.samples import Samples
from model.fit.spec import LAMBERT, ggx_conductor, lambert_ggx
from model.geometry import degrees_to_vector

PLASTIC = CookTorrance(alpha=0.2, fresnel="dielectric", eta=1.5, rho_d=(0.3, 0.2, 0.1))
LADDER = [LAMBERT, lambert_ggx("dielectric"), lambert_ggx("schlick").per_channel("f0"), ggx_conductor()]
#: Seconds a process waits for the other to begin a fit before it goes on alone (the test then fails).
PATIENCE_S = 60.0


def samples() -> Samples:
    """Two in-plane slices of a plastic with 1 % seeded noise and a small direction covariance (angular errors)."""
    to = np.array([-70.0, -50.0, -30.0, -10.0, 0.0, 10.0, 30.0, 50.0, 70.0])
    wi = np.concatenate([np.repeat(degrees_to_vector(t, 0.0)[None], len(to), axis=0) for t in (20.0, 50.0)])
    wo = np.concatenate([degrees_to_vector(np.abs(to), np.where(to > 0, 180.0, 0.0))] * 2)
    f = np.asarray(PLASTIC.eval(wi, wo), dtype=np.float64)
    se = 0.01 * f
    noisy = f + se * np.random.default_rng(3).standard_normal(f.shape)
    cov = np.broadcast_to(np.eye(4) * 1e-6, (len(wi), 4, 4)).copy()
    return Samples(wi, wo, noisy, se, direction_cov=cov)


def fitted(jobs: int) -> tuple[Any, dict[str, float], list[str], dict[str, Any], list[str]]:
    lines: list[str] = []
    angular: dict[str, Any] = {}
    selection, times, caught = fit_ladder(samples(), LADDER, starts=2, log=lines.append, angular=angular, jobs=jobs)
    return selection, times, caught, angular, [re.sub(r"\(\d+\.\d+ s\)", "(s)", line) for line in lines]


def wrapped(tmp: Path, parent: int, then: Callable[[], None] = lambda: None) -> Callable[..., Any]:
    """_fit_candidate noting which process fitted each candidate; this process's first fit waits (polling, with a
    timeout) until the other process has begun one, so both are seen fitting however loaded the machine is."""
    real = ladder_mod._fit_candidate
    began = tmp / "other-began"

    def fit_candidate(*args: Any) -> Any:
        if os.getpid() != parent:
            began.touch()
            then()
        elif not (tmp / "waited").exists():
            (tmp / "waited").touch()
            deadline = time.monotonic() + PATIENCE_S
            while not began.exists() and time.monotonic() < deadline:
                time.sleep(0.005)  # a poll, not a wait for time to pass: the other process needs this core
        cand, seconds, caught, variance = real(*args)
        return cand, seconds, [*caught, f"pid {os.getpid()}"], variance

    return fit_candidate


ROOT = Path(__file__).resolve().parents[2]


def in_fresh_interpreter(check: str, tmp: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "tests.analysis.test_ladder", check, str(tmp)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stdout + done.stderr


def test_two_processes_fit_what_one_does(tmp_path: Path) -> None:
    in_fresh_interpreter("two_processes", tmp_path)


def test_a_helper_that_dies_leaves_its_candidates_here(tmp_path: Path) -> None:
    in_fresh_interpreter("helper_dies", tmp_path)


def two_processes(tmp: Path) -> None:
    from model.runtime import fork_safe

    one = fitted(jobs=1)
    assert fork_safe(), "a fresh interpreter should be safe to fork"
    ladder_mod._fit_candidate = wrapped(tmp, os.getpid())  # the forked process inherits it
    two = fitted(jobs=2)
    pids = {w for w in two[2] if w.startswith("pid ")}
    assert len(pids) == 2, f"one process fitted every candidate: {pids}"
    assert [w for w in two[2] if not w.startswith("pid ")] == one[2]
    assert two[0].chosen_name == one[0].chosen_name
    for a, b in zip(one[0].candidates, two[0].candidates, strict=True):
        assert a.name == b.name and a.error == b.error
        np.testing.assert_array_equal(a.result.values, b.result.values)  # the same fit to the last bit, whoever made it
        np.testing.assert_array_equal(a.result.covariance, b.result.covariance)
        assert a.result.chi2 == b.result.chi2
    assert list(two[1]) == list(one[1]) == [s.name for s in LADDER]
    assert two[3].keys() == one[3].keys() and all(np.array_equal(two[3][k], one[3][k]) for k in one[3])
    assert two[4] == one[4] and len(one[4]) == len(LADDER)  # logged in ladder order either way


def helper_dies(tmp: Path) -> None:
    one = fitted(jobs=1)
    ladder_mod._fit_candidate = wrapped(tmp, os.getpid(), then=lambda: os._exit(3))
    two = fitted(jobs=2)
    assert {w for w in two[2] if w.startswith("pid ")} == {f"pid {os.getpid()}"}
    assert [c.name for c in two[0].candidates] == [c.name for c in one[0].candidates]
    for a, b in zip(one[0].candidates, two[0].candidates, strict=True):
        np.testing.assert_array_equal(a.result.values, b.result.values)
    assert two[4] == one[4]


if __name__ == "__main__":
    {"two_processes": two_processes, "helper_dies": helper_dies}[sys.argv[1]](Path(sys.argv[2]))
    print("ok")
