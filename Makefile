# Two commands a user needs: `make run` (the main job: training) and `make test` (the test suite).
# `make demo` runs the scripted controller; ARGS="key=value ..." passes overrides to run and demo.
# Both create .venv in the checkout and install the project from pyproject.toml.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

# Offscreen rendering for evaluation videos (MUJOCO_GL=egl with Mesa's software renderer): Debian /
# Ubuntu packages, installed only when missing (sudo when not root); a failure is only a warning.
GL_PACKAGES := libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0 libgl1
# A C compiler for the tests' fake Kinova Gen2 SDK (tests/fake_kinova_sdk), installed only when no
# cc is on PATH; without one those tests skip, saying so.
CC_PACKAGES := gcc libc6-dev
# libusb for Kinova's Gen2 USB communication layer (ahrm_stack/hardware/vendor/kinova_gen2/, loaded by the
# Gen2 backend and by its tests), installed only when missing.
USB_PACKAGES := libusb-1.0-0

.PHONY: run demo test lint bench setup clean system-deps

$(STAMP): pyproject.toml
	@$(MAKE) --no-print-directory system-deps
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[dev]"
	touch $(STAMP)

setup: $(STAMP)

system-deps:
	@if ! command -v dpkg >/dev/null 2>&1; then \
	  echo "note: no dpkg; evaluation videos need EGL (or OSMesa) OpenGL libraries, Kinova's Gen2 SDK libusb-1.0"; exit 0; fi; \
	missing=""; for p in $(GL_PACKAGES) $(USB_PACKAGES); do \
	  dpkg -s $$p 2>/dev/null | grep -q "^Status: install ok installed" || missing="$$missing $$p"; done; \
	if ! command -v cc >/dev/null 2>&1; then for p in $(CC_PACKAGES); do \
	  dpkg -s $$p 2>/dev/null | grep -q "^Status: install ok installed" || missing="$$missing $$p"; done; fi; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo -n"; fi; \
	echo "installing$$missing (offscreen rendering for evaluation videos; a C compiler for the fake Kinova SDK; libusb for Kinova's Gen2 SDK)"; \
	( $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq \
	    --no-install-recommends $$missing ) \
	  || echo "warning: could not install$$missing; MUJOCO_GL=egl (the default here) needs the GL ones, the Gen2 fake-SDK tests a C compiler, Kinova's Gen2 SDK libusb-1.0-0"

run: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m ahrm_stack.train $(ARGS)

demo: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m ahrm_stack.demo $(ARGS)

# Lint (ruff) and type check (mypy) first: settings in pyproject.toml. Then every test: those not
# marked realtime on every core (pytest-xdist; tests marked xdist_group(name) share one worker:
# Kinova's machine-wide SDK lock), then the realtime ones (wall-clock timing, tests/conftest.py)
# alone in one process. The parallel part prints its 25 slowest tests (the test-time budget).
test: lint
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest -q -n auto --dist loadgroup -m "not realtime" --durations=25 $(PYTEST_ARGS)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest -q -m realtime $(PYTEST_ARGS)

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m mypy

# Every benchmark compares two things in one run and prints the ratio; BENCH_ARGS=--quick: brief runs.
bench: $(STAMP)
	@for b in benchmarks/bench_*.py; do echo "== $$b"; \
	  MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) $$b $(BENCH_ARGS) || { echo "$$b failed"; exit 1; }; done

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis .mypy_cache .ruff_cache
