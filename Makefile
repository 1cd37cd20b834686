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

.PHONY: install install-core run test lint typecheck pytest bench fuzz fixtures gpu-wheels gpu-ort-parts gpu-check-dry clean

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

# The GPU check (docs/gpu.md, "The GPU check"): the wheels the GPU machine lacks (Python 3.12,
# x86_64, no registry there) and YOLOX-Nano, into the git-ignored .whl/ that the device call
# carries. Exact pins, each one's needs named too (--no-deps): the core dependencies that machine
# lacks, onnx2torch (engine torch) and jsonschema (the test suite checks every run.json).
# Not carried, over the 64 MiB the tree may carry: onnxruntime-gpu 1.31.1 (243.7 MiB), which
# travels in parts instead (gpu-ort-parts below), and ray 2.60.0 (75.6 MiB), so no Ray sweep cell.
GPU_WHEELS := mcap==1.6.0 mcap-ros2-support==0.6.0 mcap-protobuf-support==0.6.0 \
	rosbags==0.11.9 apsw==3.54.1.0 backports.zstd==1.8.0 zstandard==0.25.0 lz4==4.4.5 \
	ruamel.yaml==0.19.1 onnx2torch==1.5.15 jsonschema==4.26.0 jsonschema-specifications==2025.9.1 \
	referencing==0.37.0 rpds-py==2026.9.1
GPU_PLATFORMS := $(foreach n,2_28 2_27 2_17,--platform manylinux_$(n)_x86_64) \
	--platform manylinux2014_x86_64 --platform manylinux1_x86_64
YOLOX := ../shared/real/models/yolox_nano.onnx

gpu-wheels:
	rm -rf .whl && mkdir -p .whl/models
	$(PYTHON) -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
		--implementation cp $(GPU_PLATFORMS) -d .whl $(GPU_WHEELS)
	if [ -f $(YOLOX) ]; then cp $(YOLOX) .whl/models/; else echo "$(YOLOX) not found: the YOLOX-Nano steps will be skipped"; fi
	du -sb .whl
	@echo 'tracked tree:' $$(git ls-files -z | xargs -0 du -cb | tail -1)

# onnxruntime-gpu for `cuda --engine ort`, cut into the git-ignored .ortparts/ (40 MiB parts and
# their manifest), one part a device call, joined there into .whl/ before the GPU check
# (benchmarks/wheel_parts.py, docs/gpu.md); `calls` prints the device calls
ORT_GPU := onnxruntime-gpu==1.31.1

gpu-ort-parts:
	rm -rf .ortparts && mkdir -p .ortparts/download
	$(PYTHON) -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
		--implementation cp $(GPU_PLATFORMS) -d .ortparts/download $(ORT_GPU)
	$(PYTHON) -m benchmarks.wheel_parts split .ortparts/download/*.whl .ortparts
	rm -rf .ortparts/download
	$(PYTHON) -m benchmarks.wheel_parts calls .ortparts

# the GPU check on the CPU: small inputs, no wheels, GPU steps replaced or skipped with the reason
gpu-check-dry:
	benchmarks/gpu_check.sh --dry-run --out replaybench-runs/gpu-check-dry --work replaybench-runs/gpu-check-dry/work

clean:
	rm -rf $(VENV) replaybench-runs .pytest_cache .mypy_cache .ruff_cache
