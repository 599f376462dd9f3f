# Two set-up commands on a fresh machine (Python 3.11):
#   make run    install and run the main job
#   make test   install with the test extras, lint, run the test suite (what CI runs)
#   make docs   build the documentation site (warnings are errors) and serve it on http://127.0.0.1:8000

PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
MAIN_JOB ?= configs/block_world_proficiency.yaml
# setuptools says "Editable installation. Please be careful with folders ..." on every editable install of a
# package-dir layout; it is about editable installs in general, not this project (tests/test_packaging.py
# builds the wheel and checks that setuptools warns of nothing)
PIP_QUIET := PYTHONWARNINGS="ignore:Editable installation" $(BIN)/python -m pip install --quiet

.PHONY: run test lint bench clean browser docs rt-tests

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.run-deps: pyproject.toml | $(BIN)/python
	$(PIP_QUIET) -e '.[ompl]'
	touch $@

$(VENV)/.test-deps: pyproject.toml examples/surgiplan-hello/pyproject.toml | $(BIN)/python
	$(PIP_QUIET) -e '.[dev,dask,ompl,browser,pardiso,interop,mcap,docs]' -e examples/surgiplan-hello
	touch $@ $(VENV)/.run-deps

# $(call apt_install,COMMAND,PACKAGE,FOR WHAT,WITHOUT IT): nothing when COMMAND is there; else, as root with apt,
# install Debian's PACKAGE (apt-get update only when the plain install fails); else say what WITHOUT IT happens.
# A failed install warns and goes on: what needs the tool says so itself (a skip, or a row naming what is missing).
define apt_install
@command -v $(1) >/dev/null 2>&1 || { \
  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
    echo "installing $(2) (apt) for $(3)"; \
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q $(2) >/dev/null 2>&1 || \
    { apt-get update -q >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -q $(2) >/dev/null; } || \
    echo "warning: could not install $(2): $(4)"; \
  else echo "warning: no $(1) and no root to install it (apt-get install $(2)): $(4)"; fi; }
endef

# The browser tests (report.html, the live view) drive Debian's chromium through Playwright's client
# (never `playwright install`, which downloads a browser build). Quick when it is there; installed with
# apt where we may (CI runs as root); elsewhere those tests skip and say why (with CI set they fail instead,
# tests/ci_skips.py: CI cannot pass with its browser or interop peers missing).
browser:
	$(call apt_install,chromium,chromium,the browser tests,the browser tests will skip (fail with CI set))

run: $(VENV)/.run-deps
	$(BIN)/surgiplan run $(MAIN_JOB)

lint: $(VENV)/.test-deps
	$(BIN)/ruff check .

test: lint browser rt-tests
	$(BIN)/python -m pytest -q

# the site: Sphinx with warnings as errors (-W: a broken link, an unresolved reference, an undocumented public
# name), then served on 127.0.0.1 only (Ctrl-C stops); DOCS_PORT picks the port
DOCS_PORT ?= 8000
docs: $(VENV)/.test-deps
	$(BIN)/sphinx-build -q -b html -W --keep-going docs build/docs
	@echo "serving build/docs on http://127.0.0.1:$(DOCS_PORT)/ (Ctrl-C stops)"
	$(BIN)/python -m http.server --bind 127.0.0.1 --directory build/docs $(DOCS_PORT)

# The real-time benchmarks measure the machine's own floor with rt-tests' cyclictest (Debian package rt-tests), and
# a test checks how they read it: installed with apt where we may, as chromium is; elsewhere that test skips and
# the benchmark's row says cyclictest is missing.
rt-tests:
	$(call apt_install,cyclictest,rt-tests,the real-time benchmarks' floor,the benchmarks' cyclictest floor will say so)

bench: $(VENV)/.test-deps rt-tests
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf out .pytest_cache
