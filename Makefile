# Two commands a user needs: `make run` (the main job: training) and `make test` (the test suite).
# `make demo` runs the scripted controller; ARGS="key=value ..." passes overrides to run and demo.
# Both create .venv in the checkout and install the project from pyproject.toml.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: run demo test bench setup clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e ".[dev]"
	touch $(STAMP)

setup: $(STAMP)

run: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m ahrm_stack.train $(ARGS)

demo: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m ahrm_stack.demo $(ARGS)

test: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest -q

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(PY) $$b || exit 1; done

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
