# Two commands do all the set-up on a fresh machine:
#   make demo   -> builds the embedded synthetic mission and runs the main job on it
#   make test   -> runs the test suite
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# two stamps: the demo needs the viz extra only; the tests and the lint need the dev extras
DEMO_STAMP := $(VENV)/.installed-demo
DEV_STAMP := $(VENV)/.installed-dev
WARM_STAMP := $(VENV)/.warmed
KERNEL_SOURCES := $(shell grep -rl --include='*.py' '@njit' mars_pairs)
# every pip call is constrained: torch stays the local CPU build (torch==2.13.0)
PIP := $(PY) -m pip install -q -c constraints.txt

.PHONY: demo test test-fast lint docs bench clean

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(DEMO_STAMP): pyproject.toml constraints.txt | $(VENV)/bin/python
	$(PIP) torch==2.13.0
	$(PIP) -e '.[viz]'
	touch $(DEMO_STAMP)

# numba compiles every kernel the commands run, once, into its cache beside the package
# (__pycache__), after the install and again when a module with kernels changes (numba's
# cache goes stale with its source): no command's first call compiles
$(WARM_STAMP): $(DEMO_STAMP) $(KERNEL_SOURCES)
	$(PY) -m mars_pairs.warmup
	touch $(WARM_STAMP)

$(DEV_STAMP): pyproject.toml constraints.txt $(DEMO_STAMP)
	$(PIP) -e '.[dev,viz,dask,lightning]'
	touch $(DEV_STAMP)

demo: $(WARM_STAMP)
	$(VENV)/bin/mars-pairs build --config configs/demo.yaml --workers 2
	$(VENV)/bin/mars-pairs inspect out/demo/dataset

test: $(DEV_STAMP) $(WARM_STAMP)
	$(PY) -m pytest -q -n auto

# the development lane: every test but those marked slow (CI's `make test` runs them all)
test-fast: $(DEV_STAMP) $(WARM_STAMP)
	$(PY) -m pytest -q -n auto -m "not slow"

docs: $(DEV_STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

lint: $(DEV_STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

bench: $(DEV_STAMP)
	$(PY) benchmarks/bench_viewshed.py
	$(PY) benchmarks/bench_build.py
	$(PY) benchmarks/bench_loader.py
	$(PY) benchmarks/bench_plan.py

clean:
	rm -rf out site .pytest_cache
