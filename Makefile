# Two commands do all the set-up on a fresh machine:
#   make demo   -> builds the embedded synthetic mission and runs the main job on it
#   make test   -> runs the test suite
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
TORCH := torch==2.13.0

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# the local CPU build of torch first, so the project's range needs nothing more
	$(PY) -m pip install -q $(TORCH)
	$(PY) -m pip install -q -e '.[dev,viz,dask]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/mars-pairs build --config configs/demo.yaml --workers 2
	$(VENV)/bin/mars-pairs inspect out/demo/dataset

test: $(STAMP)
	$(PY) -m pytest -q

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

bench: $(STAMP)
	$(PY) benchmarks/bench_viewshed.py
	$(PY) benchmarks/bench_build.py
	$(PY) benchmarks/bench_loader.py
	$(PY) benchmarks/bench_plan.py

clean:
	rm -rf out .pytest_cache
