# floaff-zoo: every target does its own set-up (idempotent, stamp file).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.floaff-stamp
export MUJOCO_GL ?= egl
export OMP_NUM_THREADS ?= 2
export PYTHONHASHSEED := 0

.PHONY: setup lint test test-slow demo bench clean-data sysdeps
LINT_PATHS := src tests benchmarks

sysdeps:
	@if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then \
	  echo "[setup] installing Debian package libusb-1.0-0 (needed by open3d)"; \
	  if [ "$$(id -u)" = 0 ]; then SUDO=""; else SUDO="sudo"; fi; \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null; \
	fi

$(STAMP): pyproject.toml | sysdeps
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# the local CPU wheel first, so nothing pulls a multi-GB CUDA build
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e ".[dev]"
	@touch $(STAMP)

setup: sysdeps $(STAMP)

lint: setup
	$(BIN)/ruff check $(LINT_PATHS)
	$(BIN)/ruff format --check $(LINT_PATHS)

# lint first: a style slip fails in seconds, before the suite's minutes. The suite runs in TEST_WORKERS processes
# (pytest-xdist), one file per worker at a time so a module's fixtures are built once: the suite keeps about one core
# busy, and 2 workers on the 2-core CI machine take about 2,100 tests in 9-12 minutes. TEST_WORKERS=0 runs it
# in one process.
TEST_WORKERS ?= 2
test: setup
	$(BIN)/ruff check $(LINT_PATHS)
	$(BIN)/ruff format --check $(LINT_PATHS)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-slow: setup
	$(BIN)/python -m pytest -q -m slow -n $(TEST_WORKERS) --dist loadfile

demo: setup
	$(BIN)/python -m floaff_zoo demo

bench: setup
	$(BIN)/python benchmarks/run_all.py

clean-data:
	rm -rf data runs
