# Every target creates .venv and installs the project itself: nothing to set up by hand.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: test demo bench lint clean

# A pipeline fails when pip does, not only when its last command does.
SHELL := /bin/bash
.SHELLFLAGS := -o pipefail -c

# Passes pip's output through as it comes and prints a dot after each second and a half of
# silence (pip says nothing for seconds while it builds or resolves): never silent for long.
define TICKER
import os, select, sys
fd, out = sys.stdin.fileno(), sys.stdout.buffer
while True:
    ready, _, _ = select.select([fd], [], [], 1.5)
    if not ready:
        out.write(b"."); out.flush(); continue
    data = os.read(fd, 65536)
    if not data:
        break
    out.write(data); out.flush()
endef
export TICKER
TICK := $(PYTHON) -u -c "$$TICKER"

# pip shows what it fetches and installs (a progress bar per download on a terminal).
$(STAMP): pyproject.toml
	@echo "==> setting up $(VENV): agrifleet and its dependencies (numpy, numba, shapely, zenoh, ...)"
	@echo "    first time only, a minute or two; again only when pyproject.toml changes"
	@# `python -m venv` says nothing for seconds while it installs pip: a dot a second.
	@test -x $(BIN)/python || { \
	  printf '    creating $(VENV) '; \
	  $(PYTHON) -m venv $(VENV) & pid=$$!; \
	  while kill -0 $$pid 2>/dev/null; do printf .; sleep 1; done; \
	  wait $$pid && echo ' done'; }
	$(BIN)/python -m pip install --disable-pip-version-check --progress-bar on --upgrade pip 2>&1 | $(TICK)
	$(BIN)/python -m pip install --disable-pip-version-check --progress-bar on -e '.[test,dev,bench]' 2>&1 | $(TICK)
	@# The solver's numba kernels, compiled once for this install (~30 s, and says so):
	@# plans, tests and benchmarks then load them from numba's cache at once.
	$(BIN)/agrifleet warm
	@touch $(STAMP)
	@echo "==> $(VENV) ready"

# Two workers: the process tests mostly wait on simulated tractors (the suite keeps one core
# busy about a third of the time), so two halve the wall time on a 2-core machine.
test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2

demo: $(STAMP)
	$(BIN)/agrifleet demo $(DEMO_ARGS)

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py $(BENCH_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy agrifleet planner dispatcher sim_vehicles
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
