# needlekit: set-up, demo and tests. `make demo` and `make test` work on a fresh machine
# with Python 3.11+ and make: they create .venv and install into it first.

PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-test
OUT    ?= out/demo
# Two workers suit the 2-core machines CI and the developers use; override with JOBS=1.
JOBS   ?= 2

# Debian's Chromium and its driver, for the test that opens every report kind in a real
# browser (tests/test_browser.py): installed once when missing and apt-get can.
CHROMIUM ?= /usr/bin/chromium

# The OpenIGTLink C++ library's own example programs (Debian's openigtlink-examples sources
# against libopenigtlink-dev), for the live-link test against a peer nobody here wrote
# (tests/execute/test_igtl_cpp.py): ReceiveClient reads what `execute --igtl` sends,
# TrackerServer is a tracker whose transforms are not the needle's.
IGTL_EXAMPLES_SRC ?= /usr/share/doc/openigtlink-examples/examples
IGTL_EXAMPLES     ?= .cache/igtl-examples

.PHONY: help install demo test test-fast lint bench clean browser igtl-examples

help:
	@echo "make demo   - create .venv, install needlekit, run the demo into $(OUT)"
	@echo "make test   - create .venv, install needlekit with test extras, run the tests"
	@echo "make browser - install Debian's chromium and chromium-driver (for the browser test)"
	@echo "make igtl-examples - build OpenIGTLink's C++ examples (for the live-link interop test)"
	@echo "make lint   - ruff check"
	@echo "make bench  - run the benchmarks into out/bench"
	@echo "make clean  - remove .venv, out/ and caches"

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "needlekit needs Python 3.11 or newer; set PYTHON=python3.11")'
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

# --no-compile, then compileall on two processes: pip would byte-compile every installed
# package on one (27 s). Compiled they must be: where PYTHONDONTWRITEBYTECODE is set (CI
# sandboxes, many containers) Python never writes what it compiles, so every process would
# compile numpy, scipy, numba and plotly again: measured 7-9 s of a 16-25 s `needlekit
# puncture --trials 1`, for every command a test starts. Both steps: about 32 s, once.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --no-compile -e '.[test]'
	$(BIN)/python -m compileall -q -j $(JOBS) src \
		"$$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')" >/dev/null \
		|| echo "compileall: some files did not compile; Python compiles them on import instead"
	$(BIN)/python -m needlekit._warmup
	@touch $@

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/needlekit demo --out $(OUT)

browser:
	@if [ -x $(CHROMIUM) ] && [ -x /usr/bin/chromedriver ]; then :; \
	elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
		echo "installing Debian's chromium and chromium-driver for the browser test"; \
		apt-get install -y -qq chromium chromium-driver >/dev/null \
		|| (apt-get update -qq && apt-get install -y -qq chromium chromium-driver >/dev/null) \
		|| echo "could not install chromium: the browser test will be skipped"; \
	else echo "no chromium and no root apt-get: the browser test will be skipped"; fi

igtl-examples:
	@if [ -d $(IGTL_EXAMPLES_SRC) ] && [ -d /usr/lib/openigtlink ] && command -v cmake >/dev/null 2>&1 \
		&& command -v c++ >/dev/null 2>&1; then :; \
	elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
		echo "installing Debian's libopenigtlink-dev and openigtlink-examples (cmake, g++)"; \
		apt-get install -y -qq cmake g++ libopenigtlink-dev openigtlink-examples >/dev/null \
		|| (apt-get update -qq && apt-get install -y -qq cmake g++ libopenigtlink-dev openigtlink-examples >/dev/null) \
		|| echo "could not install OpenIGTLink: the C++ interop test will be skipped"; \
	else echo "no OpenIGTLink and no root apt-get: the C++ interop test will be skipped"; fi
	@if [ -d $(IGTL_EXAMPLES_SRC) ] && command -v cmake >/dev/null 2>&1; then \
		for d in Tracker Receiver; do \
			cmake -S $(IGTL_EXAMPLES_SRC)/$$d -B $(IGTL_EXAMPLES)/$$d -DCMAKE_BUILD_TYPE=Release \
				-Wno-dev >/dev/null || exit 1; \
		done; \
		cmake --build $(IGTL_EXAMPLES)/Tracker --target TrackerServer >/dev/null && \
		cmake --build $(IGTL_EXAMPLES)/Receiver --target ReceiveClient >/dev/null && \
		echo "built $(IGTL_EXAMPLES)/Tracker/TrackerServer and $(IGTL_EXAMPLES)/Receiver/ReceiveClient"; \
	fi

# --durations=10: every run names its ten slowest tests, the first place to look when the
# suite's time grows
test: $(STAMP) browser igtl-examples
	$(BIN)/python -m pytest -n $(JOBS) --dist loadscope -q --durations=10

test-fast: $(STAMP)
	$(BIN)/python -m pytest -n $(JOBS) --dist loadscope -q -m "not slow"

lint: $(STAMP)
	$(BIN)/python -m pip install --quiet ruff
	$(BIN)/ruff check src tests

bench: $(STAMP)
	$(BIN)/needlekit bench kinematics --out out/bench/kinematics.json

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache .hypothesis
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
