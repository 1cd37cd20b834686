# replaybench: `make run` installs and runs the main job on a bundled fixture bag;
# `make test` installs and runs lint, types and the test suite.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install run test lint typecheck pytest bench fuzz fixtures clean

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev,train]'
	# the cuda backend's torch engine, tested on the CPU: onnx2torch without its torchvision
	# requirement (PyPI's torchvision does not import beside the CPU build of torch)
	$(BIN)/python -m pip install -q --no-deps 'onnx2torch==1.5.15'
	touch $(STAMP)

run: install
	$(BIN)/replaybench run fixtures/bags/rgb8_raw.mcap --backend hsv --backend null --out replaybench-runs/demo --force

lint: install
	$(BIN)/ruff check replaybench tests benchmarks training
	$(BIN)/ruff format --check replaybench tests benchmarks training

typecheck: install
	$(BIN)/mypy

pytest: install
	$(BIN)/pytest -n 2 -q

test: lint typecheck pytest

bench: install
	$(BIN)/python -m benchmarks

fuzz: install
	REPLAYBENCH_FUZZ=long $(BIN)/pytest tests/fuzz -q -n auto

fixtures: install
	$(BIN)/replaybench fixtures --out fixtures/bags

clean:
	rm -rf $(VENV) replaybench-runs .pytest_cache .mypy_cache .ruff_cache
