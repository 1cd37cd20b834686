"""Skips and paths shared by the GPU backend tests (imported as ``backends.gpu.gpuhelpers``)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from replaybench.backends.gpu._cuda import driver_problem

REAL = (Path(__file__).resolve().parents[3] / '..' / 'shared' / 'real').resolve()
YOLOX_NANO = REAL / 'models' / 'yolox_nano.onnx'
ASTRONAUT = REAL / 'images' / 'astronaut.png'
FIXTURE_BAGS = Path(__file__).resolve().parents[3] / 'fixtures' / 'bags'


def has(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


#: Skips for tests that need a module or an NVIDIA GPU; the reason says what is missing.
needs_torch = pytest.mark.skipif(not has('torch'), reason='torch is not installed')
needs_scipy = pytest.mark.skipif(not has('scipy'), reason='scipy is not installed')
needs_gpu = pytest.mark.skipif(
    driver_problem() is not None, reason=f'needs an NVIDIA GPU: {driver_problem()}'
)
