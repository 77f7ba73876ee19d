# selfsupport — build, demo and tests. Needs only python3 (>= 3.11) and pip.
#   make demo        create .venv, install the project, solve the built-in demo -> demo-out/
#   make test        create .venv, install with the test extra, run the fast test suite
#   make test-slow   run the tests marked slow
#   make fuzz        property-based fuzzing with the large hypothesis profile
#   make clean       remove .venv, stamps and demo output
# Installs are stamp-file based: they rerun only when pyproject.toml changes.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP_RUN  := $(VENV)/.installed-run
STAMP_TEST := $(VENV)/.installed-test

.PHONY: demo test test-slow test-all fuzz clean venv

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP_RUN): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(STAMP_TEST): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@ $(STAMP_RUN)

venv: $(STAMP_RUN)

demo: $(STAMP_RUN)
	$(BIN)/selfsupport demo

# -n auto: one pytest-xdist worker per core (on a 2-core machine the fast suite took 4.2 min
# instead of 9.0 serially, 2026-11-28). The browser tests run afterwards, alone: they time a
# drag against the design server's answers, which a busy second worker delayed past the drag.
test: $(STAMP_TEST)
	$(BIN)/pytest -q -m "not slow and not browser" -n auto
	$(BIN)/pytest -q -m "browser and not slow"

test-slow: $(STAMP_TEST)
	$(BIN)/pytest -q -m slow

test-all: $(STAMP_TEST)
	$(BIN)/pytest -q

fuzz: $(STAMP_TEST)
	HYPOTHESIS_PROFILE=fuzz $(BIN)/pytest -q tests/test_fuzz.py --hypothesis-show-statistics

clean:
	rm -rf $(VENV) demo-out .pytest_cache
