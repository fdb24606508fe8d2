"""Tests of model.mitsuba.variant: probing, fallback order, the override and the context manager.

The failure paths use real failures, not mocks: a subprocess started with DRJIT_LIBLLVM_PATH
pointing at a missing file cannot load any llvm variant (drjit reads the path once per process),
and one pointing at LLVM 15, where installed, loads a variant whose code generation aborts.
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from model.mitsuba import variant as mv
from tests.mitsuba_helpers import llvm_required, require_variant

pytestmark = pytest.mark.mitsuba

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(autouse=True)
def _no_override(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests start without a forced variant, whatever the calling shell exports."""
    monkeypatch.delenv(mv.ENV_VAR, raising=False)


def run_python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    """Run code in a fresh interpreter (a fresh drjit) with extra environment variables."""
    full_env = {k: v for k, v in os.environ.items() if k != mv.ENV_VAR}
    full_env.update(env)
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=REPO,
        env=full_env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def diffuse_eval(name: str) -> float:
    """One cosine-weighted eval of a 0.5 diffuse BSDF under ``name``: runs a real kernel."""
    with mv.use_variant(name):
        bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}})
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(0.0, 0.0, 1.0)
        value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0.6, 0.0, 0.8))
        return float(np.asarray(value).ravel()[0])


def test_scalar_rgb_always_loads() -> None:
    assert mv.unavailable_reason("scalar_rgb") is None
    assert "scalar_rgb" in mv.available_variants()
    assert diffuse_eval("scalar_rgb") == pytest.approx(0.5 / np.pi * 0.8, rel=1e-6)


def test_llvm_rgb_loads_when_promised() -> None:
    # Skips without libLLVM >= 16, but fails when GONIO_REQUIRE_LLVM=1 (CI installs libllvm19).
    require_variant("llvm_ad_rgb")
    assert "llvm_ad_rgb" in mv.available_variants()
    # Compiling and running a BSDF kernel is what LLVM 15 could not do; this one must.
    assert diffuse_eval("llvm_ad_rgb") == pytest.approx(0.5 / np.pi * 0.8, rel=1e-6)


def test_fallback_order_is_llvm_then_scalar() -> None:
    assert mv.candidates("rgb") == ["llvm_ad_rgb", "scalar_rgb"]
    available = mv.available_variants("rgb")
    assert available == [v for v in mv.candidates("rgb") if v in available]
    assert mv.pick_variant() == available[0]
    if llvm_required():
        assert mv.pick_variant() == "llvm_ad_rgb"


def test_pick_falls_back_to_scalar_when_llvm_does_not_load(monkeypatch: pytest.MonkeyPatch) -> None:
    # The cached probe result is what pick_variant consults; the real failure is exercised in a
    # subprocess below.
    monkeypatch.setitem(mv._reasons, "llvm_ad_rgb", "simulated: no libLLVM")
    assert mv.pick_variant() == "scalar_rgb"
    assert mv.available_variants() == ["scalar_rgb"]


def test_prefer_is_tried_first_and_falls_back(monkeypatch: pytest.MonkeyPatch) -> None:
    assert mv.pick_variant(prefer="scalar_rgb") == "scalar_rgb"
    assert mv.pick_variant(prefer="bogus_rgb") == mv.pick_variant()
    monkeypatch.setitem(mv._reasons, "llvm_ad_rgb", "simulated: no libLLVM")
    assert mv.pick_variant(prefer="llvm_ad_rgb") == "scalar_rgb"


def test_prefer_of_another_kind_is_refused() -> None:
    with pytest.raises(mv.VariantUnavailable, match="'spectral' variant; the caller needs 'rgb'"):
        mv.pick_variant(prefer="scalar_spectral")


def test_environment_variable_forces_its_variant(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(mv.ENV_VAR, "scalar_rgb")
    assert mv.pick_variant() == "scalar_rgb"
    assert mv.pick_variant(prefer="llvm_ad_rgb") == "scalar_rgb"  # the variable beats prefer


def test_forcing_a_bogus_variant_is_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(mv.ENV_VAR, "bogus_rgb")
    with pytest.raises(mv.VariantUnavailable) as info:
        mv.pick_variant()
    message = str(info.value)
    assert "'bogus_rgb'" in message and mv.ENV_VAR in message
    assert "not a variant of this Mitsuba build" in message and "scalar_rgb" in message


def test_forcing_a_variant_that_fails_to_load_names_it_and_the_cause(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(mv.ENV_VAR, "llvm_ad_rgb")
    monkeypatch.setitem(mv._reasons, "llvm_ad_rgb", "ImportError: simulated")
    with pytest.raises(mv.VariantUnavailable, match=r"'llvm_ad_rgb' \(forced by GONIO_MITSUBA_VARIANT\).*simulated"):
        mv.pick_variant()


def test_missing_libllvm_in_a_real_process() -> None:
    # drjit reads DRJIT_LIBLLVM_PATH once, at its first llvm use, so this needs a fresh process.
    code = """
        from model.mitsuba import variant as mv
        print("PICK", mv.pick_variant())
        print("AVAILABLE", mv.available_variants())
        try:
            with mv.use_variant("llvm_ad_rgb"):
                pass
        except mv.VariantUnavailable as exc:
            print("ERROR", exc)
    """
    out = run_python(code, DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM.so")
    assert out.returncode == 0, out.stderr
    lines = dict(line.split(" ", 1) for line in out.stdout.splitlines())
    assert lines["PICK"] == "scalar_rgb"
    assert lines["AVAILABLE"] == "['scalar_rgb']"
    assert "'llvm_ad_rgb'" in lines["ERROR"] and "libLLVM" in lines["ERROR"]
    assert "apt-get install libllvm19" in lines["ERROR"]


def test_forced_llvm_without_libllvm_fails_in_a_real_process() -> None:
    out = run_python(
        "from model.mitsuba import variant as mv; mv.pick_variant()",
        DRJIT_LIBLLVM_PATH="/nonexistent/libLLVM.so",
        GONIO_MITSUBA_VARIANT="llvm_ad_rgb",
    )
    assert out.returncode != 0
    assert "VariantUnavailable" in out.stderr and "'llvm_ad_rgb'" in out.stderr
    assert "apt-get install libllvm19" in out.stderr


def test_llvm_15_is_rejected_before_it_can_abort() -> None:
    # With LLVM 15, set_variant succeeds and the first BSDF kernel aborts the process in code
    # generation, so the probe must refuse it by version. Only testable where LLVM 15 is installed.
    found = sorted(glob.glob("/usr/lib/*/libLLVM-15.so*") + glob.glob("/lib/*/libLLVM-15.so*"))
    if not found:
        pytest.skip("no libLLVM-15 installed here to test the version check against")
    code = """
        from model.mitsuba import variant as mv
        print(mv.unavailable_reason("llvm_ad_rgb"))
        print(mv.pick_variant())
    """
    out = run_python(code, DRJIT_LIBLLVM_PATH=found[0])
    assert out.returncode == 0, out.stderr
    reason, picked = out.stdout.strip().splitlines()
    assert reason.startswith("libLLVM 15.") and "too old" in reason and "libllvm19" in reason
    assert picked == "scalar_rgb"


def test_probe_results_are_cached(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[str] = []
    real = mv._try_load

    def counting(name: str) -> str | None:
        calls.append(name)
        return real(name)

    monkeypatch.setattr(mv, "_try_load", counting)
    monkeypatch.setattr(mv, "_reasons", {})
    for _ in range(3):
        mv.unavailable_reason("scalar_rgb")
        mv.pick_variant()
    assert calls.count("scalar_rgb") == 1
    assert len(calls) == len(set(calls))
    mv.clear_cache()
    mv.unavailable_reason("scalar_rgb")
    assert calls.count("scalar_rgb") == 2


def test_probing_leaves_the_active_variant_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mv, "_reasons", {})
    with mv.use_variant("scalar_rgb"):
        mv.available_variants(None)  # probes every built variant, llvm and cuda included
        assert mi.variant() == "scalar_rgb"


def test_use_variant_sets_and_restores(monkeypatch: pytest.MonkeyPatch) -> None:
    other = mv.pick_variant()  # llvm where it loads, else scalar again: both paths are valid
    with mv.use_variant("scalar_rgb") as outer:
        assert outer == "scalar_rgb" and mi.variant() == "scalar_rgb"
        with mv.use_variant(other):
            assert mi.variant() == other
        assert mi.variant() == "scalar_rgb"
        with mv.use_variant("scalar_rgb"):  # already active: a no-op both ways
            assert mi.variant() == "scalar_rgb"
        assert mi.variant() == "scalar_rgb"
        with pytest.raises(RuntimeError, match="inside"), mv.use_variant(other):
            raise RuntimeError("inside")
        assert mi.variant() == "scalar_rgb"
        with pytest.raises(mv.VariantUnavailable, match="bogus_rgb"), mv.use_variant("bogus_rgb"):
            pass
        assert mi.variant() == "scalar_rgb"


def test_kind_of_variant_names() -> None:
    assert mv.kind_of("llvm_ad_rgb") == "rgb"
    assert mv.kind_of("scalar_spectral_polarized") == "spectral_polarized"
    assert mv.kind_of("cuda_ad_mono") == "mono"
    assert mv.kind_of("bogus_rgb") is None  # left to the probe, which lists the real variants


def test_forcing_a_variant_of_another_kind_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(mv.ENV_VAR, "scalar_spectral")
    with pytest.raises(mv.VariantUnavailable, match="'spectral' variant; the caller needs 'rgb'"):
        mv.pick_variant()
    assert mv.pick_variant(kind="spectral") == "scalar_spectral"
