#!/usr/bin/env bash
# The prepared GPU check (docs/gpu.md, "The GPU check"): on a machine with an NVIDIA GPU, installs
# the carried wheels (.whl/, `make gpu-wheels`), writes its inputs and runs every step with its own
# time limit, logging each step's exit status and going on; packs everything into
# $OUT/gpu-check.tar.gz (or --out DIR). `--dry-run`: the same on the CPU, small and fast.
#
#   benchmarks/gpu_check.sh [--dry-run] [--out DIR] [--budget S] ...   (--help lists the options)
set -euo pipefail
cd "$(dirname "$0")/.."
# the GPU machine's python3 holds torch, CuPy and onnxruntime; here, the project's environment
PY="${PYTHON:-}"
if [ -z "$PY" ]; then
    if [ -x .venv/bin/python ]; then PY=.venv/bin/python; else PY=python3; fi
fi
export PYTHONUNBUFFERED=1
exec "$PY" -m benchmarks.gpu_check "$@"
