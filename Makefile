# cnctwin: two commands do everything on a fresh machine (Python 3.11+).
#   make demo   set up .venv, simulate, analyse, write the report
#   make test   set up .venv, run ruff, mypy and pytest
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
# make demo installs cnctwin and its run-time dependencies only; make test adds the extras
# (web, mqtt, opcua, postgres, ...) and the development tools (BENCHMARKS.md, "footprint")
DEMO_STAMP := $(VENV)/.installed-demo
STAMP  := $(VENV)/.installed
OUT    ?= out/demo

.PHONY: demo test lint typecheck pytest services bench clean docs

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "cnctwin needs Python 3.11 or newer")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(DEMO_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	@touch $(DEMO_STAMP)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[all,dev]'
	@touch $(STAMP) $(DEMO_STAMP)

demo: $(DEMO_STAMP)
	$(BIN)/cnctwin demo --out $(OUT)

test: $(STAMP) lint typecheck pytest

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/lint-imports

typecheck: $(STAMP)
	$(BIN)/mypy

services:
	@bash scripts/ensure-services.sh

pytest: $(STAMP) services
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q --durations=15

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

docs: $(STAMP)
	$(BIN)/python -m cnctwin.signals --glossary docs/glossary.md

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache
