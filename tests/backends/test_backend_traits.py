"""What a backend declares beyond its methods (``Backend`` device, latency, recorded input)."""

from __future__ import annotations

from typing import ClassVar

import pytest

from replaybench.backends import BUILTIN_BACKENDS, get_backend
from replaybench.backends.base import BackendTraits, backend_traits
from replaybench.errors import BackendUnavailableError


class _Plain:
    name: ClassVar[str] = 'plain'


class _OnTheGpu:
    name: ClassVar[str] = 'on-gpu'
    device: ClassVar[str] = 'cuda'


class _BadDevice:
    name: ClassVar[str] = 'bad-device'
    device: ClassVar[str] = 'gpu'


class _BadFlag:
    name: ClassVar[str] = 'bad-flag'
    measures_latency: ClassVar[object] = 'no'


def test_a_backend_that_declares_nothing_gets_the_defaults():
    assert backend_traits(_Plain) == BackendTraits('cpu', True, False)
    assert backend_traits(_Plain()) == BackendTraits('cpu', True, False)


def test_the_builtin_backends_state_their_device_and_whether_they_are_timed():
    traits = {name: backend_traits(get_backend(name)) for name in BUILTIN_BACKENDS}
    assert {n for n, t in traits.items() if t.device == 'cuda'} == {
        'cuda',
        'tensorrt',
        'hsv-cuda',
        'cuda-stereo',
        'tensorrt-stereo',
    }
    assert {n for n, t in traits.items() if not t.measures_latency} == {'recorded'}
    assert {n for n, t in traits.items() if t.uses_recorded_detections} == {'recorded'}
    assert backend_traits(_OnTheGpu).device == 'cuda'


@pytest.mark.parametrize(
    ('cls', 'message'),
    [
        (_BadDevice, "'bad-device' declares device 'gpu'; use one of cpu, cuda"),
        (_BadFlag, "'bad-flag' declares measures_latency 'no'; it must be True or False"),
    ],
)
def test_a_declared_value_of_the_wrong_kind_is_refused_naming_the_backend(cls, message):
    with pytest.raises(BackendUnavailableError, match=message):
        backend_traits(cls)


def test_no_backend_name_list_is_kept_outside_the_registry():
    from pathlib import Path

    import replaybench

    root = Path(replaybench.__file__).parent
    for path in [*root.glob('cli/*.py'), *root.glob('replay/*.py'), *root.glob('app/*.py')]:
        text = path.read_text(encoding='utf-8')
        for name in ("'cuda'", "'tensorrt'", "'hsv-cuda'"):
            code = [line for line in text.splitlines() if name in line and '#' not in line]
            assert not [line for line in code if 'device' not in line], (path, name, code)
        assert 'RecordedBackend' not in text, path


def test_only_the_backends_that_never_read_a_frames_camera_info_say_so():
    traits = {name: backend_traits(get_backend(name)) for name in BUILTIN_BACKENDS}
    silent = {n for n, t in traits.items() if not t.reads_camera_info}
    assert {'null', 'hsv', 'hsv-seg', 'onnx-cpu', 'onnx-seg', 'recorded'} <= silent
    assert not {'apriltag', 'aruco'} & silent  # their poses need the intrinsics
