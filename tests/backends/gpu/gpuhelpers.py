"""Skips and paths shared by the GPU backend tests (imported as ``backends.gpu.gpuhelpers``)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from replaybench.backends.gpu._cuda import driver_problem
from replaybench.types import FrameSet

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


def stereo_pairs(bag: Path) -> list[FrameSet]:
    """The bag's stereo pairs as FrameSets, each member with its CameraInfo."""
    from replaybench.decode import decode_camera_info, decode_image
    from replaybench.sources import open_source

    infos, images = {}, {}
    with open_source(bag) as source:
        for msg in source.messages():
            if msg.topic.endswith('camera_info'):
                infos[msg.topic.split('/')[2]] = decode_camera_info(msg)
            elif msg.topic.startswith('/stereo/'):
                frame = decode_image(msg)
                side = msg.topic.split('/')[2]
                images[(frame.stamp_ns, side)] = frame._replace(camera_info=infos[side])
    stamps = sorted({stamp for stamp, _ in images})
    return [FrameSet((images[(s, 'left')], images[(s, 'right')])) for s in stamps]
