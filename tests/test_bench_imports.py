"""Every benchmark imports: a module moved under it (as bench._tradeoff did) breaks `make bench`, not the suite."""

import importlib
import pkgutil

import pytest

import bench

MODULES = sorted(m.name for m in pkgutil.iter_modules(bench.__path__))


def test_the_benchmarks_are_found():
    assert "calibration_payoff" in MODULES and "geometry_calibration" in MODULES


@pytest.mark.parametrize("name", MODULES)
def test_every_benchmark_imports(name):
    module = importlib.import_module(f"bench.{name}")
    if not name.startswith("_"):
        assert callable(getattr(module, "main", None)), f"bench.{name} has no main()"
