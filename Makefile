# needlekit: set-up, demo and tests. `make demo` and `make test` work on a fresh machine
# with Python 3.11+ and make: they create .venv and install into it first.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-test
OUT    ?= out/demo
# Two workers suit the 2-core machines CI and the developers use; override with JOBS=1.
JOBS   ?= 2

.PHONY: help install demo test test-fast lint bench clean

help:
	@echo "make demo   - create .venv, install needlekit, run the demo into $(OUT)"
	@echo "make test   - create .venv, install needlekit with test extras, run the tests"
	@echo "make lint   - ruff check"
	@echo "make bench  - run the benchmarks into out/bench"
	@echo "make clean  - remove .venv, out/ and caches"

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "needlekit needs Python 3.11 or newer; set PYTHON=python3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e '.[test]'
	$(BIN)/python -m needlekit._warmup
	@touch $@

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/needlekit demo --out $(OUT)

test: $(STAMP)
	$(BIN)/python -m pytest -n $(JOBS) -q

test-fast: $(STAMP)
	$(BIN)/python -m pytest -n $(JOBS) -q -m "not slow"

lint: $(STAMP)
	$(BIN)/python -m pip install --quiet ruff
	$(BIN)/ruff check src tests

bench: $(STAMP)
	$(BIN)/needlekit bench kinematics --out out/bench/kinematics.json

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache .hypothesis
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
