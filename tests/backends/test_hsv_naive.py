"""The hsv backend gives exactly the detections of the naive lab-node port it replaces."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from replaybench.backends import BackendOptions
from replaybench.backends.hsv import HsvBackend, HsvConfig, parse_config

if TYPE_CHECKING:
    from types import ModuleType

NAIVE = Path(__file__).resolve().parents[2] / 'benchmarks' / 'naive_hsv.py'

Scene = Any


@pytest.fixture(scope='module')
def naive() -> ModuleType:
    spec = importlib.util.spec_from_file_location('naive_hsv', NAIVE)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules['naive_hsv'] = module
    spec.loader.exec_module(module)
    return module


def random_scene(scene: type[Scene], seed: int) -> Scene:
    """Saturated rectangles, discs and triangles, some touching, some clipped by the border."""
    rng = np.random.default_rng(seed)
    s = scene(width=480, height=360, seed=seed, noise=10.0)
    colours = ['red', 'green', 'blue', 'yellow', (60, 0, 230), (90, 160, 200)]
    for _ in range(int(rng.integers(8, 20))):
        colour = colours[int(rng.integers(0, len(colours)))]
        x, y = int(rng.integers(-20, 470)), int(rng.integers(-20, 350))
        size = int(rng.integers(4, 70))
        shape = int(rng.integers(0, 3))
        if shape == 0:
            s.rect(colour, x, y, x + size, y + int(rng.integers(4, 70)))
        elif shape == 1:
            s.disc(colour, x, y, size // 2)
        else:
            s.poly(colour, [(x, y), (x + size, y), (x, y + size)])
    return s


@pytest.mark.parametrize('seed', range(6))
@pytest.mark.parametrize('encoding', ['bgr8', 'rgb8'])
def test_hsv_matches_the_naive_port_on_random_scenes(
    naive: ModuleType, scene: type[Scene], seed: int, encoding: str
) -> None:
    s = random_scene(scene, seed)
    backend = HsvBackend()
    backend.open()
    fast = list(backend.detect(s.frame(encoding)).detections)
    slow = naive.naive_detect(s.pixels(encoding), encoding)
    assert len(slow) >= 3
    assert fast == slow


@pytest.mark.parametrize(
    'detector',
    [
        {'min_area': 0, 'kernel': 3, 'open_iterations': 2, 'close_iterations': 1},
        {'min_area': 30, 'kernel': 7, 'open_iterations': 0, 'close_iterations': 2},
        {'min_area': 10, 'kernel': 1},
    ],
)
def test_hsv_matches_the_naive_port_with_other_detector_settings(
    naive: ModuleType, scene: type[Scene], detector: dict[str, Any]
) -> None:
    config = parse_config({'detector': detector})
    s = random_scene(scene, 42)
    backend = HsvBackend(BackendOptions(extra={k: str(v) for k, v in detector.items()}))
    assert backend.config == config
    backend.open()
    fast = list(backend.detect(s.frame('bgr8')).detections)
    assert fast == naive.naive_detect(s.pixels('bgr8'), 'bgr8', config)
    assert fast


def test_the_naive_port_uses_the_default_config(naive: ModuleType, scene: type[Scene]) -> None:
    s = random_scene(scene, 3)
    assert naive.naive_detect(s.pixels(), 'bgr8') == naive.naive_detect(
        s.pixels(), 'bgr8', HsvConfig()
    )
