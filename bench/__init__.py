"""Benchmarks (see docs/benchmarks.md); each prints its figures and its ratio to an anchor of the same run."""

import model.runtime  # noqa: F401 (the thread pools' policy, as in every entry point: model/runtime.py)
