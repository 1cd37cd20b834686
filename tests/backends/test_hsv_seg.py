"""hsv-seg: per-pixel colour classes, equal pixel for pixel to the naive per-class port."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest

from replaybench.backends import BackendOptions, get_backend
from replaybench.backends.hsv import HsvConfig, parse_config
from replaybench.backends.hsv_seg import HsvSegBackend
from replaybench.errors import BackendError
from replaybench.fixtures.scene import Scene
from replaybench.types import Frame

if TYPE_CHECKING:
    from types import ModuleType

NAIVE = Path(__file__).resolve().parents[2] / 'benchmarks' / 'naive_hsv_seg.py'


@pytest.fixture(scope='module')
def naive() -> ModuleType:
    spec = importlib.util.spec_from_file_location('naive_hsv_seg', NAIVE)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules['naive_hsv_seg'] = module
    spec.loader.exec_module(module)
    return module


def _frame(image: np.ndarray, encoding: str = 'bgr8') -> Frame:
    return Frame('/camera/image_raw', 0, 0, 0, 'cam', image, encoding, encoding)


def _labels(backend: HsvSegBackend, image: np.ndarray, encoding: str = 'bgr8') -> np.ndarray:
    result = backend.detect(_frame(image, encoding))
    assert result.detections == ()
    assert result.mask is not None
    return result.mask.labels


def test_the_backend_is_registered_and_names_background_first() -> None:
    assert get_backend('hsv-seg') is HsvSegBackend
    backend = HsvSegBackend(BackendOptions())
    assert backend.class_names == ('background', 'red', 'green', 'blue', 'yellow')


def test_a_hand_drawn_frame_gets_exact_class_ids() -> None:
    image = np.full((40, 60, 3), 128, np.uint8)
    image[5:15, 5:25] = (0, 0, 230)  # red
    image[20:35, 30:55] = (230, 40, 0)  # blue
    backend = HsvSegBackend(BackendOptions(extra={'kernel': '1'}))
    labels = _labels(backend, image)
    expected = np.zeros((40, 60), np.uint8)
    expected[5:15, 5:25] = 1
    expected[20:35, 30:55] = 3
    assert labels.dtype == np.uint8
    assert labels.flags.c_contiguous
    assert np.array_equal(labels, expected)
    # the same picture as rgb8 gives the same mask
    assert np.array_equal(_labels(backend, image[:, :, ::-1].copy(), 'rgb8'), expected)


@pytest.mark.parametrize(('size', 'index'), [((320, 240), 3), ((640, 480), 11), ((97, 61), 5)])
def test_scene_frames_match_the_naive_port_pixel_for_pixel(
    naive: ModuleType, size: tuple[int, int], index: int
) -> None:
    scene = Scene(size, seed=7)
    backend = HsvSegBackend()
    for i in range(index, index + 4):
        image, _ = scene.render(i)
        assert np.array_equal(_labels(backend, image), naive.naive_segment(image))


def test_specks_noise_and_borders_match_the_naive_port(naive: ModuleType) -> None:
    rng = np.random.default_rng(11)
    for seed in range(3):
        hsv = rng.integers(0, 256, size=(130, 170, 3), dtype=np.uint8)
        hsv[:, :, 0] %= 180
        # big saturated patches of each hue, some on the border, over random speckle
        for _ in range(8):
            x, y = (int(v) for v in rng.integers(-10, 160, size=2))
            w, h = (int(v) for v in rng.integers(3, 60, size=2))
            hue = int(rng.choice([0, 5, 60, 115, 28, 175]))
            cv2.rectangle(hsv, (x, y), (x + w, y + h), (hue, 220, 200), -1)
        image = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
        for extra in ({}, {'kernel': '7', 'open_iterations': '2'}, {'close_iterations': '0'}):
            backend = HsvSegBackend(BackendOptions(extra=extra))
            labels = _labels(backend, image)
            assert np.array_equal(labels, naive.naive_segment(image, backend.config)), (
                seed,
                extra,
            )


def test_overlapping_classes_go_to_the_first_in_the_configuration(
    naive: ModuleType, tmp_path: Path
) -> None:
    config = parse_config(
        {
            'detector': {'kernel': 1},
            'classes': [
                {'name': 'warm', 'ranges': [[[0, 100, 70], [40, 255, 255]]]},
                {'name': 'orange', 'ranges': [[[5, 100, 70], [25, 255, 255]]]},
            ],
        }
    )
    hsv = np.zeros((4, 3, 3), np.uint8)
    hsv[:, :] = (15, 200, 200)  # inside both classes
    hsv[0, 0] = (30, 200, 200)  # warm only
    hsv[3, 2] = (90, 200, 200)  # neither
    image = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    backend = _with_config(config, tmp_path)
    labels = _labels(backend, image)
    assert labels[1, 1] == 1
    assert labels[0, 0] == 1
    assert labels[3, 2] == 0
    assert np.array_equal(labels, naive.naive_segment(image, config))


def _with_config(config: HsvConfig, folder: Path) -> HsvSegBackend:
    from replaybench.backends.hsv import config_to_toml

    path = folder / 'seg.toml'
    path.write_text(config_to_toml(config), encoding='utf-8')
    return HsvSegBackend(BackendOptions(config=path))


def test_more_than_eight_ranges_use_several_bit_groups(naive: ModuleType, tmp_path: Path) -> None:
    classes = [
        {'name': f'hue{h}', 'ranges': [[[h, 60, 60], [h + 9, 255, 255]]]} for h in range(0, 180, 10)
    ]
    config = parse_config({'detector': {'kernel': 3}, 'classes': classes})
    backend = _with_config(config, tmp_path)
    hsv = np.zeros((60, 180, 3), np.uint8)
    hsv[:, :, 0] = np.arange(180, dtype=np.uint8)[None, :]
    hsv[:, :, 1:] = 220
    hsv[20:40, :, 1] = 20  # an unsaturated band: background
    image = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    labels = _labels(backend, image)
    assert set(np.unique(labels).tolist()) == set(range(19))
    assert np.array_equal(labels, naive.naive_segment(image, config))


def test_each_frame_gets_its_own_mask_array() -> None:
    backend = HsvSegBackend()
    image = np.full((20, 20, 3), 128, np.uint8)
    first = _labels(backend, image)
    image[:, :] = (0, 0, 230)
    second = _labels(backend, image)
    assert first is not second
    assert int(first.max()) == 0
    assert int(second.min()) == 1


def test_bad_options_and_images_are_one_clear_error() -> None:
    with pytest.raises(BackendError, match='hsv-seg: unknown option'):
        HsvSegBackend(BackendOptions(extra={'colour': 'red'}))
    backend = HsvSegBackend()
    with pytest.raises(BackendError, match='hsv-seg: frame'):
        backend.detect(_frame(np.zeros((4, 4, 2), np.uint8), 'bgr8'))


def test_item_s_frames_at_640x480_match_the_naive_port(naive: ModuleType) -> None:
    # the twelve frames benchmarks item s times at 640x480 (benchmarks.data.scene_frames)
    scene = Scene((640, 480))
    backend = HsvSegBackend()
    for i in range(12):
        image, _ = scene.render(5 * i)
        assert np.array_equal(_labels(backend, image), naive.naive_segment(image)), i


def _every_channel_test_config() -> HsvConfig:
    """Two bytes of range bits whose channels take each kind of test: a table (H of the
    first, S of the second), a threshold from below (V of the second) and from above (V of
    the first), an interval (H of the second) and none (S of the first)."""
    first = [[[h, 0, 0], [h + 14, 255, 180]] for h in range(0, 120, 15)]
    second = [[[120, 40, 70], [180, 200, 255]], [[120, 90, 70], [180, 255, 255]]]
    classes = [{'name': f'band{i}', 'ranges': [r]} for i, r in enumerate(first[:7])]
    classes.append({'name': 'across', 'ranges': [first[7], second[0]]})
    classes.append({'name': 'purple', 'ranges': [second[1]]})
    return parse_config({'classes': classes})


def test_every_kind_of_channel_test_matches_the_naive_port(
    naive: ModuleType, tmp_path: Path, shared_real: Path
) -> None:
    config = _every_channel_test_config()
    backend = _with_config(config, tmp_path)
    tests = backend._plan.tests
    first = {t.channel: (t.lut is not None, t.lower, t.upper) for t in tests[0]}
    second = {t.channel: (t.lut is not None, t.lower, t.upper) for t in tests[1]}
    assert first == {0: (True, 0, 0), 2: (False, 0, 180)}
    assert second == {0: (False, 120, 180), 1: (True, 0, 0), 2: (False, 70, 255)}
    photo = cv2.imread(str(shared_real / 'images' / 'astronaut.png'), cv2.IMREAD_COLOR)
    assert photo is not None
    scene = Scene((320, 240), seed=3)
    images = [photo, photo[100:300, 50:411], *(scene.render(i)[0] for i in (0, 9))]
    for number, image in enumerate(images):
        labels = _labels(backend, image)
        assert np.array_equal(labels, naive.naive_segment(image, config)), number
    assert len(np.unique(_labels(backend, photo))) >= 5  # the photo reaches many classes


def test_a_real_photo_matches_the_naive_port_with_the_default_classes(
    naive: ModuleType, shared_real: Path
) -> None:
    photo = cv2.imread(str(shared_real / 'images' / 'astronaut.png'), cv2.IMREAD_COLOR)
    assert photo is not None
    backend = HsvSegBackend()
    for extra in ({}, {'kernel': '9', 'close_iterations': '2'}):
        backend = HsvSegBackend(BackendOptions(extra=extra))
        labels = _labels(backend, photo)
        assert np.array_equal(labels, naive.naive_segment(photo, backend.config)), extra
        assert int(labels.max()) > 0


def _random_config(rng: np.random.Generator) -> HsvConfig:
    """Up to 6 classes of up to 3 ranges (up to 18: several bytes of bits); S and V shared by
    every range (interval tests) or drawn per range (tables); any kernel and iterations."""
    shared = bool(rng.random() < 0.5)
    # shared S and V intervals: from 0 or above, to 255 or below (each kind of interval test)
    s_low, v_low = (int(v) * int(rng.random() < 0.7) for v in rng.integers(1, 150, size=2))
    s_high, v_high = (255 - int(v) * int(rng.random() < 0.4) for v in rng.integers(0, 100, size=2))
    classes = []
    for number in range(int(rng.integers(1, 7))):
        ranges = []
        for _ in range(int(rng.integers(1, 4))):
            h0 = int(rng.integers(0, 181))
            h1 = int(rng.integers(h0, 181))
            if shared:
                low, high = [h0, s_low, v_low], [h1, s_high, v_high]
            else:
                s0, v0 = (int(v) for v in rng.integers(0, 256, size=2))
                low = [h0, s0, v0]
                high = [h1, int(rng.integers(s0, 256)), int(rng.integers(v0, 256))]
            ranges.append([low, high])
        classes.append({'name': f'class{number}', 'ranges': ranges})
    detector = {
        'kernel': int(rng.choice([1, 3, 5, 7, 9])),
        'open_iterations': int(rng.integers(0, 3)),
        'close_iterations': int(rng.integers(0, 3)),
    }
    return parse_config({'detector': detector, 'classes': classes})


def test_random_configurations_and_frames_match_the_naive_port(
    naive: ModuleType, tmp_path: Path
) -> None:
    rng = np.random.default_rng(2611)
    for case in range(30):
        config = _random_config(rng)
        backend = _with_config(config, tmp_path)
        if case % 2:
            width, height = (int(v) for v in rng.integers(20, 400, size=2))
            image, _ = Scene((width, height), seed=case).render(int(rng.integers(0, 50)))
        else:
            shape = (int(rng.integers(10, 200)), int(rng.integers(10, 200)), 3)
            hsv = rng.integers(0, 256, size=shape, dtype=np.uint8)
            hsv[:, :, 0] %= 180
            for _ in range(10):
                x, y = (int(v) for v in rng.integers(-10, 200, size=2))
                w, h = (int(v) for v in rng.integers(1, 80, size=2))
                colour = (int(rng.integers(0, 180)), int(rng.integers(0, 256)), 220)
                cv2.rectangle(hsv, (x, y), (x + w, y + h), colour, -1)
            image = np.asarray(cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR))
        expected = naive.naive_segment(image, config)
        for _ in range(2):  # the second frame reuses the work images of the first
            assert np.array_equal(_labels(backend, image), expected), case
