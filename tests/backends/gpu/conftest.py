"""Fixtures of the GPU backend tests: the real YOLOX-Nano model, a tiny ONNX model, and a
fake CUDA driver (``driver``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from backends.gpu.gpufakes import FakeGpu, FakeLibcuda, install_libcuda
from backends.gpu.gpuhelpers import YOLOX_NANO
from detector.onnxgraph import Output, write_model

from replaybench.backends.gpu import _cuda

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
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


@pytest.fixture
def driver(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., FakeLibcuda]]:
    """``driver(gpus, visible=None, version=13000, release=None)`` answers the CUDA driver
    queries with a ``FakeLibcuda`` for the rest of the test."""

    def install(
        gpus: list[FakeGpu],
        visible: list[int] | None = None,
        version: int = 13000,
        release: str | None = None,
    ) -> FakeLibcuda:
        fake = FakeLibcuda(list(gpus), visible, version)
        install_libcuda(monkeypatch, fake, release)
        return fake

    yield install
    _cuda._device_count.cache_clear()
