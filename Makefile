# The README's two commands: `make run` (the main job) and `make test`.
# Both create what they need on first use: .venv from requirements.txt and the
# colcon build of src/ into install/.
SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
STAMP_VENV := $(VENV)/.installed
STAMP_BUILD := install/.built
STAMP_TRAIN := $(VENV)/.train-installed
PKG_META := $(wildcard src/*/setup.py src/*/setup.cfg src/*/package.xml src/*/resource/* src/*/config/*)
RUN_ARGS ?= --sim --lockstep --duration 30 --record runs --plots
# Byte-code caches on (git ignores them): without them every test run re-writes the tests'
# asserts (5 s a collection) and every `cartpole` subprocess compiles the packages again.
unexport PYTHONDONTWRITEBYTECODE

.PHONY: run test test-fast docs train-deps build venv clean bench help firmware-deps

help:
	@echo "make run   - simulated swing-up with the default controllers, recorded and summarised"
	@echo "make test  - build and run the whole test suite"
	@echo "make test-fast - the tests that need neither a ROS graph nor real time (while working)"
	@echo "make docs  - build the documentation site into build/docs/html (warnings are errors)"
	@echo "make build - (re)build the colcon workspace"
	@echo "make clean - remove build/, install/, log/ (keeps .venv)"

venv: $(STAMP_VENV)
$(STAMP_VENV): requirements.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found (Python 3.11+ is needed); set PYTHON=..." >&2; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q -r requirements.txt
	touch $@

build: $(STAMP_BUILD)
# --symlink-install links the sources (needs the venv's default setuptools 65.x),
# so editing Python needs no rebuild; package metadata changes do.
$(STAMP_BUILD): $(STAMP_VENV) $(PKG_META)
	source ./env.sh --no-overlay && flock .build.lock colcon build --symlink-install \
	    --event-handlers console_cohesion- summary- status- --base-paths src
	touch $@

# The firmware tests on the emulated Cortex-M3 need gcc-arm-none-eabi, libnewlib-arm-none-eabi and
# qemu-system-arm: installed here when missing and we are root (CI); else those tests skip, naming them.
# Two xdist workers: the ROS-graph tests (marker ros) run one after another on one of them, the
# rest spread over both at a lower CPU priority (conftest.py). Then the tests marked alone (the
# rig path against the emulated device) with the machine to themselves (exit 5: none selected).
# TEST_ARGS adds pytest options.
TEST_ARGS ?=
test: $(STAMP_BUILD) firmware-deps $(STAMP_TRAIN)
	source ./env.sh && python -m pytest -q -n 2 --dist loadgroup -m "not alone" $(TEST_ARGS) && \
	    { python -m pytest -q -m alone $(TEST_ARGS); rc=$$?; [ $$rc -eq 0 ] || [ $$rc -eq 5 ]; }

# The day-to-day loop: no rclpy/DDS (marker ros), no long closed-loop runs (marker slow).
test-fast: $(STAMP_BUILD)
	source ./env.sh && python -m pytest -q -n 2 --dist loadscope -m "not ros and not slow" $(TEST_ARGS)

# The documentation site (Sphinx, MyST Markdown, the API reference from the docstrings).
docs: $(STAMP_BUILD)
	source ./env.sh && python -m sphinx -W --keep-going -q -b html docs build/docs/html
	@echo "site: build/docs/html/index.html"

# The training extra of cartpole_learning (`cartpole train`): torch (CPU-only wheel) and
# stable-baselines3. torch declares setuptools>=77, which colcon's --symlink-install cannot use:
# the venv's setuptools goes back to 65.5.0 afterwards.
# make test installs it too (the suite's training smoke test); where it cannot be installed,
# make says so and those tests skip, naming it.
train-deps: $(STAMP_TRAIN)
$(STAMP_TRAIN): $(STAMP_VENV) requirements-train.txt
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q -r requirements-train.txt \
	    && touch $@ || echo "make: the training extra (requirements-train.txt) did not install;" \
	    "the training tests skip" >&2
	$(VENV)/bin/python -m pip install --disable-pip-version-check -q setuptools==65.5.0

firmware-deps:
	@$(MAKE) -s -C firmware arm-deps

# make run also animates the run it recorded (the newest runs/*/bag) into run.gif next to its plots.
run: $(STAMP_BUILD)
	source ./env.sh && cartpole run $(RUN_ARGS) && \
	bag=$$(ls -td runs/*/bag 2>/dev/null | head -1) && if [ -n "$$bag" ]; then \
	    cartpole analyze "$$bag" --animate "$${bag%/bag}/run.gif" --json > /dev/null && \
	    echo "animation: $${bag%/bag}/run.gif"; fi

bench: $(STAMP_BUILD)
	source ./env.sh && cartpole bench all

clean:
	rm -rf build install log
