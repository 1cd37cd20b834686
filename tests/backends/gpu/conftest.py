"""Fixtures of the GPU backend tests: the real YOLOX-Nano model and a tiny ONNX model."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from backends.gpu.gpuhelpers import YOLOX_NANO
from detector.onnxgraph import Output, write_model

if TYPE_CHECKING:
    from pathlib import Path


@pytest.fixture
def yolox_nano() -> Path:
    """The real YOLOX-Nano model of shared/real, or a skip."""
    if not YOLOX_NANO.is_file():
        pytest.skip(f'{YOLOX_NANO} not present (real recordings are optional)')
    return YOLOX_NANO


@pytest.fixture
def tiny_model(tmp_path: Path) -> Path:
    """A 64x32 YOLOv8-layout model with 2 classes and one box, written in the real format."""
    out = np.zeros((1, 6, 42), np.float32)
    out[0, :, 5] = [20.0, 12.0, 16.0, 8.0, 0.9, 0.1]
    return write_model(
        tmp_path / 'tiny.onnx',
        [Output('output0', out)],
        input_shape=(1, 3, 32, 64),
        metadata={'names': 'a,b', 'replaybench.family': 'yolov8'},
    )
