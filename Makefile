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

bench: $(STAMP)
	$(BIN)/python -m bench.model_throughput
	$(BIN)/python -m bench.model_tradeoffs
	$(BIN)/python -m bench.hdr
	$(BIN)/python -m bench.exposure_plan
	$(BIN)/python -m bench.bus_latency
	$(BIN)/python -m bench.simulator
	$(BIN)/python -m bench.sweep
	$(BIN)/python -m bench.fit
	$(BIN)/python -m bench.batch
	$(BIN)/python -m bench.analyze
	$(BIN)/python -m bench.tabulated
	$(BIN)/python -m bench.camera_calibration
	$(BIN)/python -m bench.geometry_calibration --rigs 8
	$(BIN)/python -m bench.calibration_payoff

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache
