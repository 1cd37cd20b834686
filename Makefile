# replaybench: `make run` installs the core tier and runs the main job on a bundled fixture bag;
# `make test` installs the development tier and runs lint, types and the test suite.
#
# Two install tiers share one virtual environment, each with its own stamp file, so `make run`
# after `make test` (and the other way round) reuses what is there:
#   core: `pip install -e .` only: what run, info, compare and report need (no torch, no
#         browser, no linters; see README.md for its size)
#   dev:  the core tier plus the dev and train extras (tests, lint, types, the browser driver,
#         CPU torch) and onnx2torch
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
CORE_STAMP := $(VENV)/.installed-core
DEV_STAMP  := $(VENV)/.installed-dev

.PHONY: install install-core run test lint typecheck pytest bench fuzz fixtures clean

install: $(DEV_STAMP)

install-core: $(CORE_STAMP)

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

# --no-compile: Python compiles the modules it imports on first use, not every module up front
$(CORE_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q --no-compile -e .
	touch $(CORE_STAMP)

$(DEV_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[dev,train]'
	# the cuda backend's torch engine, tested on the CPU: onnx2torch without its torchvision
	# requirement (PyPI's torchvision does not import beside the CPU build of torch)
	$(BIN)/python -m pip install -q --no-deps 'onnx2torch==1.5.15'
	touch $(DEV_STAMP) $(CORE_STAMP)

run: install-core
	$(BIN)/replaybench run fixtures/bags/rgb8_raw.mcap --backend hsv --backend null --out replaybench-runs/demo --force
	@echo
	@echo 'replaybench is installed in $(VENV). In a new shell, activate it first:'
	@echo '    . $(VENV)/bin/activate'
	@echo 'or call $(BIN)/replaybench directly. Then try the examples in README.md.'

lint: install
	$(BIN)/ruff check replaybench tests benchmarks training
	$(BIN)/ruff format --check replaybench tests benchmarks training
	$(BIN)/lint-imports

typecheck: install
	$(BIN)/mypy

# the tests that gate on timings (marker quiet) run alone, after the parallel suite
pytest: install
	$(BIN)/pytest -n 2 -q -m 'not quiet'
	$(BIN)/pytest -q -p no:xdist -m quiet

test: lint typecheck pytest

bench: install
	$(BIN)/python -m benchmarks

fuzz: install
	REPLAYBENCH_FUZZ=long $(BIN)/pytest tests/fuzz -q -n auto

fixtures: install-core
	$(BIN)/replaybench fixtures --out fixtures/bags

clean:
	rm -rf $(VENV) replaybench-runs .pytest_cache .mypy_cache .ruff_cache
