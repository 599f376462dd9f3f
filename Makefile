# Two set-up commands on a fresh machine (Python 3.11):
#   make run    install and run the main job
#   make test   install with the test extras, lint, run the test suite (what CI runs)

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
MAIN_JOB ?= configs/block_world_proficiency.yaml

.PHONY: run test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.run-deps: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[ompl]'
	touch $@

$(VENV)/.test-deps: pyproject.toml examples/surgiplan-hello/pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[dev,dask,ompl,interop]' -e examples/surgiplan-hello
	touch $@ $(VENV)/.run-deps

run: $(VENV)/.run-deps
	$(BIN)/surgiplan run $(MAIN_JOB)

lint: $(VENV)/.test-deps
	$(BIN)/ruff check .

test: lint
	$(BIN)/python -m pytest -q

bench: $(VENV)/.test-deps
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf out .pytest_cache
