# rs_localizer: two commands on a machine with nothing but Python 3.11
#   make demo   the node on the sample bag over DDS, accuracy vs ground truth (and vs p3p)
#   make test   the style gate (ruff) and the whole test suite
# Other targets: venv, tf2-msgs (/tf on the PyPI wheels), test-quick (no node over DDS, no slow
# test), lint, format, params (the parameters' defaults in docs and config from their table),
# sample-bag (regenerate the committed bags), bench-node, fuzz-long, newcomer (the docs'
# commands, run), clean.

PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
PY     := $(BIN)/python
RSL    := $(BIN)/rs-localizer
STAMP  := $(VENV)/.rs_localizer-installed
PYTEST_ARGS ?= -q

.PHONY: venv tf2-msgs demo test test-quick lint format params sample-bag bench-node fuzz-long \
	newcomer clean

venv: $(STAMP)

# (re)install when the packaging changes; the ROS 2 Jazzy wheels come from PyPI.
# STAMP_DEPS= : a venv prepared otherwise (.ci/distro) is used as it is once it has the stamp
STAMP_DEPS ?= setup.py setup.cfg package.xml
$(STAMP): $(STAMP_DEPS)
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) (set PYTHON=...)"; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install -e '.[ros,test,bench,mapping,view]'
	touch $@

# tf2_msgs is not among the PyPI wheels: build it with their rosidl generators (needs cc, c++)
tf2-msgs: venv
	$(PY) tools/build_tf2_msgs.py

demo: venv
	$(RSL) demo $(ARGS)

# the style gate (ruff.toml): lint, import order and formatting
lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# rewrite the sources in the gate's format and apply its safe fixes
format: venv
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

# the defaults of docs/node.md, README.md and config/rs_localizer.yaml from the one table of
# the node's parameters (rs_localizer/ros/params.py PARAMETERS); test_docs_sync checks them
params: venv
	$(PY) -m rs_localizer.ros.param_docs --write

# pytest exit code 5 = no tests collected: not a failure of the build
test: venv lint
	@$(PY) -m pytest $(PYTEST_ARGS) test; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest: no tests collected"; rc=0; fi; exit $$rc

# the quick set: leaves out the tests that start nodes over DDS and those over ~10 s
test-quick: venv
	$(PY) -m pytest $(PYTEST_ARGS) -m "not ros and not slow" test

# the property-based fuzz suite with 20000 examples per test (make test runs a bounded profile)
FUZZ_EXAMPLES ?= 20000
fuzz-long: venv
	RS_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(PY) -m pytest -q -s test/test_fuzz.py \
		--hypothesis-show-statistics

# the committed bags: the demo's sample (correspondences) and a small keypoints bag for tests
sample-bag: venv
	$(RSL) make-bag data/sample --frames 30 --points 500 --no-ids --no-keypoints --seed 0 \
		--overwrite
	$(RSL) make-bag test/data/keypoints --frames 10 --points 300 --no-correspondences \
		--seed 1 --start-time 1700000100 --overwrite
	$(RSL) render-bag data/sample_images --frames 20 --mono --overwrite

bench-node: venv
	$(PY) -m benchmarks.bench_node --frames 300 --solver r6p_1lin

# a new user's first hour: the README's and the docs' shell commands as written (the quick ones;
# the others are listed with the reason), exit codes and quoted figures checked; then a marker
# user's first day as named checks (20-30 min; ARGS="--only gravity_frame", "--skip-slow",
# "--list")
newcomer: venv
	$(PY) tools/newcomer.py $(ARGS)

clean:
	rm -rf build *.egg-info .pytest_cache
