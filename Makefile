# Bootstraps a virtual environment in .venv on first use; every target sets up what it needs.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/gonio demo

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/lint-imports --no-cache

test: lint
	$(BIN)/pytest

# In the order `make bench` runs them; each rewrites its own section of docs/benchmarks.md.
BENCHMARKS := model_throughput model_tradeoffs hdr exposure_plan bus_latency simulator sweep fit batch analyze \
              tabulated camera_calibration "geometry_calibration --rigs 8" calibration_payoff image_mode \
              continuous_scan exposure_ahead adaptive_modes

bench: $(STAMP)
	for b in $(BENCHMARKS); do $(BIN)/python -m bench.$$b || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
