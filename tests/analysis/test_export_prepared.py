"""What an export standby computes before the fit (analysis.exports.write.prepare_exports) changes no export byte.

The shared draws (the albedo's uniform numbers, directions and half vectors; the projections' seeded pairs; the
error grid; the tabulation's square) are the arrays the exports computed for themselves before, now made once per
process and read-only: the same bits, whichever process made them and whether or not it made them early.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import cloudpickle
import numpy as np
import pytest

from analysis.analyze import write_report
from analysis.exports.write import ALBEDO_EVALS, export_material, prepare_exports
from analysis.result import Analysis
from model import CookTorrance, microfacet
from model import integrate as integrate_module
from model.fit import metal_roughness
from model.fit.metal_roughness import ERROR_SAMPLES, FIT_SAMPLES, sample_pairs
from model.fit.spec import ggx_conductor
from model.geometry import spherical_to_vector
from model.integrate import directional_albedo
from model.mitsuba import projection, tabulated
from tests.analysis.test_report_honesty import analysis_of, in_plane

GLOSSY = CookTorrance(alpha=0.2, fresnel="schlick", f0=(0.9, 0.7, 0.4), rho_d=(0.01, 0.02, 0.0))


def _forget() -> None:
    """Drop every process-wide cache the exports share, as in a new process."""
    projection.grid_pairs.cache_clear()
    projection.fit_pairs.cache_clear()
    projection._kept_grid_values.cache_clear()
    metal_roughness.seeded_pairs.cache_clear()
    integrate_module._draws.cache_clear()
    tabulated._square.cache_clear()


def _files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_exports_are_the_same_bytes_prepared_or_not(tmp_path: Path) -> None:
    _forget()
    export_material(GLOSSY, tmp_path / "cold")
    _forget()
    prepare_exports()
    export_material(GLOSSY, tmp_path / "prepared")
    export_material(GLOSSY, tmp_path / "again")  # the half vectors kept from the export before
    cold = _files(tmp_path / "cold")
    assert "material.bsdf" in cold and "material.json" in cold
    assert _files(tmp_path / "prepared") == cold
    assert _files(tmp_path / "again") == cold


@pytest.mark.parametrize("model", [GLOSSY, CookTorrance(alpha=0.05, fresnel="conductor", eta=0.2, k=3.0)])
def test_a_seeded_albedo_is_bit_identical_to_the_one_drawn_afresh(model: CookTorrance) -> None:
    # rng=0 goes through the shared draws, a Generator through draws of its own: the same numbers, the same bits.
    for theta in (0.0, 60.0, 85.0):
        wi = spherical_to_vector(np.radians(theta), 0.0)
        shared = directional_albedo(model, wi, n=ALBEDO_EVALS, method="mc", rng=0)
        fresh = directional_albedo(model, wi, n=ALBEDO_EVALS, method="mc", rng=np.random.default_rng(0))
        assert np.array_equal(shared.value, fresh.value) and np.array_equal(shared.stderr, fresh.stderr)


def test_half_vectors_are_the_sampled_ones() -> None:
    u1, u2 = np.random.default_rng(3).random((2, 1000))
    for kind in ("ggx", "beckmann", "blinn_phong"):
        h, pdf = microfacet.sample_half_vector(kind, 0.3, u1, u2)
        h2, cos_t = microfacet.half_vectors(kind, 0.3, u1, u2)
        assert np.array_equal(h, h2) and np.array_equal(cos_t, h[:, 2])
        assert np.all(pdf > 0)


def test_shared_pairs_are_the_ones_each_call_drew_and_cannot_be_changed() -> None:
    fit_rng, error_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(0).spawn(2))
    (wi, wo, w), (ei, eo, ew) = metal_roughness.seeded_pairs(FIT_SAMPLES, 0)
    for got, want in zip((wi, wo, w, ei, eo, ew),
                         (*sample_pairs(FIT_SAMPLES, fit_rng), *sample_pairs(ERROR_SAMPLES, error_rng)),
                         strict=True):  # fmt: skip
        assert np.array_equal(got, want)
        with pytest.raises(ValueError):
            got[0] = 0.0
    pi, po, pw = projection.fit_pairs(0)
    for got, want in zip((pi, po, pw), sample_pairs(projection.FIT_SAMPLES, np.random.default_rng(0)), strict=True):
        assert np.array_equal(got, want)
    with pytest.raises(ValueError):
        projection.grid_pairs()[0][0, 0] = 1.0


class _Handed:
    """A stand-in for a forked Standby: keeps what it is handed and runs it here when asked."""

    forked = True

    def __init__(self) -> None:
        self.calls: list[Callable[[], Any]] = []

    def run(self, fn: Callable[[], Any]) -> None:
        self.calls.append(fn)

    def result(self) -> Any:
        return self.calls[-1]()


def test_the_export_standby_is_handed_the_chosen_model_not_the_analysis(tmp_path: Path) -> None:
    # Pickled into the standby: an Analysis of a MERL source is 39 MB (its table rides along as the reference).
    truth = CookTorrance(alpha=0.3, fresnel="conductor", eta=(0.2, 0.4, 1.5), k=(3.4, 2.4, 1.9))
    a = analysis_of(in_plane(truth), [ggx_conductor()], truth=truth)
    figures, exports = _Handed(), _Handed()
    index = write_report(a, tmp_path, jobs=2, standby=figures, exporter=exports)  # type: ignore[arg-type]
    (job,) = exports.calls
    held = [c.cell_contents for c in job.__closure__ or ()]
    assert a.selection.chosen.model in held and not any(isinstance(v, Analysis) for v in held)
    assert len(cloudpickle.dumps(job)) < len(cloudpickle.dumps(a.selection.chosen.model)) + 2000  # not the samples
    assert (tmp_path / "export" / "material.json").is_file() and "material.json" in index.read_text()


def test_albedos_of_models_taken_in_turn_keep_their_own_half_vectors() -> None:
    other = CookTorrance(alpha=0.05, fresnel="conductor", eta=0.2, k=3.0)
    wi = spherical_to_vector(np.radians(30.0), 0.0)
    fresh = {m: directional_albedo(m, wi, n=4096, method="mc", rng=np.random.default_rng(1)) for m in (GLOSSY, other)}
    want = {m: est.value for m, est in fresh.items()}
    for m in (GLOSSY, other, GLOSSY, other):
        assert np.array_equal(directional_albedo(m, wi, n=4096, method="mc", rng=1).value, want[m])
