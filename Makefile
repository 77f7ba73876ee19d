# selfsupport — build, demo and tests. Needs only python3 (>= 3.11) and pip.
#   make demo        create .venv, install the project from the lock, solve the built-in demo -> demo-out/
#   make test        create .venv, install the project and its test, docs and lint extras from the lock,
#                    build the documentation, lint, run the fast suite
#   make docs        build the documentation site (MkDocs, --strict) into site/
#   make lint        ruff and the import-linter layer contracts (make test runs it)
#   make test-slow   run the tests marked slow
#   make fuzz        property-based fuzzing with the large hypothesis profile
#   make bench       run the studies behind the documentation's numbers -> benchmarks/results/*.csv and the
#                    generated page docs/benchmarks.md (50-70 minutes; BENCH_SIZES=1000,4000,16000,64000 for
#                    the big scaling sizes, BENCH_ONLY=table1,pq for some studies)
#   make lock        re-resolve requirements/*.lock from pyproject.toml's ranges (newest releases)
#   make test-latest run the fast suite against the newest releases (.venv-latest) and list what moved
#   make clean       remove the virtual environments, stamps and demo output
# Installs are stamp-file based: they rerun when pyproject.toml or a lock file changes.

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
LATEST := .venv-latest
STAMP_RUN  := $(VENV)/.installed-run
STAMP_TEST := $(VENV)/.installed-test
UV_VERSION := 0.13.9
# Every pin, transitive ones and the build backend included, for Python 3.11+ on any platform.
LOCK_FLAGS := --universal --python-version 3.11 --quiet --no-header --annotation-style line
PYTEST_FAST := -q -m "not slow and not browser" -n auto
# make bench's inputs: the paper's scenes, the original tool's build (../shared/original-tool/build.sh OUT)
# and the independent checker, beside the checkout
SCENES   ?= ../shared/paper-scenes/scenes
ORIGINAL ?= ../build/original
CHECKER  ?= ../shared/tools/check_network.py

.PHONY: demo lint test test-slow test-all test-latest fuzz lock clean venv docs bench

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

# The project itself goes in without its dependencies and without build isolation, so nothing
# but the lock's pins is ever installed.
$(STAMP_RUN): pyproject.toml requirements/run.lock | $(BIN)/python
	$(BIN)/python -m pip install --quiet -r requirements/run.lock
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $@

$(STAMP_TEST): pyproject.toml requirements/test.lock | $(BIN)/python
	$(BIN)/python -m pip install --quiet -r requirements/test.lock
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $@ $(STAMP_RUN)

venv: $(STAMP_RUN)

demo: $(STAMP_RUN)
	$(BIN)/selfsupport demo

# --strict: a broken link, a missing page or an unresolved API reference fails the build.
docs: $(STAMP_TEST)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

# ruff (pyflakes, sorted imports, heavy libraries imported only where used) and import-linter (the
# layers of the package, pyproject.toml's [tool.importlinter]): a violation fails the build.
lint: $(STAMP_TEST)
	$(BIN)/ruff check --quiet .
	$(BIN)/lint-imports --no-cache

# The documentation is built first (docs), then the lint (lint). -n auto: one pytest-xdist worker per
# core. The browser tests run afterwards, alone: they time a drag against the design server's answers,
# which a busy second worker would delay.
test: docs lint
	$(BIN)/pytest $(PYTEST_FAST)
	$(BIN)/pytest -q -m "browser and not slow"

# A study that cannot run here (no scenes, no driver) is skipped with one line; the others still run.
bench: $(STAMP_TEST)
	$(BIN)/python -m benchmarks.run --scenes $(SCENES) --original $(ORIGINAL) --checker $(CHECKER) \
		$(if $(BENCH_SIZES),--scaling-sizes $(BENCH_SIZES)) $(if $(BENCH_ONLY),--only $(BENCH_ONLY))

test-slow: $(STAMP_TEST)
	$(BIN)/pytest -q -m slow

test-all: $(STAMP_TEST)
	$(BIN)/pytest -q

fuzz: $(STAMP_TEST)
	HYPOTHESIS_PROFILE=fuzz $(BIN)/pytest -q tests/test_fuzz.py --hypothesis-show-statistics

lock: | $(BIN)/python
	$(BIN)/python -m pip install --quiet uv==$(UV_VERSION)
	$(BIN)/uv pip compile $(LOCK_FLAGS) pyproject.toml requirements/build.in -o requirements/run.lock
	$(BIN)/uv pip compile $(LOCK_FLAGS) --extra test --extra docs --extra lint pyproject.toml requirements/build.in -o requirements/test.lock

# The suite against the newest release of every dependency pyproject.toml admits: the packages
# that moved past the lock are listed first, then the suite's failures are what broke.
test-latest:
	rm -rf $(LATEST)
	$(PYTHON) -m venv $(LATEST)
	$(LATEST)/bin/python -m pip install --quiet --upgrade pip
	$(LATEST)/bin/python -m pip install --quiet --upgrade --upgrade-strategy eager -e ".[test,docs,lint]"
	$(LATEST)/bin/python requirements/drift.py requirements/test.lock
	$(LATEST)/bin/pytest $(PYTEST_FAST) -p no:cacheprovider

clean:
	rm -rf $(VENV) $(LATEST) demo-out site .pytest_cache
