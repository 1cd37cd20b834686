"""Sample thumbnails with each backend's boxes."""

from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest

from replaybench.report.samples import MAX_WIDTH, sample_relpath, write_sample
from replaybench.report.svg import colour
from replaybench.types import Detection

if TYPE_CHECKING:
    from pathlib import Path

_BAR = 20  # title bar height


def _bgr(index: int) -> np.ndarray:
    value = colour(index).lstrip('#')
    return np.array([int(value[4:6], 16), int(value[2:4], 16), int(value[0:2], 16)])


def test_thumbnail_is_scaled_and_boxes_use_the_backend_colours(tmp_path: Path) -> None:
    image = np.full((720, 1280, 3), 128, np.uint8)
    dets = {
        'hsv': [Detection(0, 'red', 0.9, 100.0, 300.0, 500.0, 600.0)],
        'onnx': [Detection(0, 'red', 0.8, 700.0, 100.0, 1200.0, 400.0)],
    }
    path = tmp_path / 'samples' / 'a.jpg'
    write_sample(path, image, dets, 'topic #1')
    thumb = cv2.imread(str(path))
    assert thumb is not None
    scale = MAX_WIDTH / 1280
    assert thumb.shape[1] == MAX_WIDTH
    assert thumb.shape[0] == round(720 * scale) + 2 * _BAR
    # middle of the left edge of each box, in thumbnail pixels
    for index, det in enumerate((dets['hsv'][0], dets['onnx'][0])):
        x = round(det.x0 * scale)
        y = round((det.y0 + det.y1) / 2 * scale) + _BAR
        pixel = thumb[y, x].astype(int)
        assert np.abs(pixel - _bgr(index)).max() < 40, (index, pixel)
    assert np.abs(thumb[_BAR + 5, MAX_WIDTH // 2].astype(int) - 128).max() < 8


def test_samples_are_byte_identical_for_the_same_input(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    image = rng.integers(0, 255, (240, 320, 3), dtype=np.uint8)
    dets = {'hsv': [Detection(0, 'blob', 0.5, 10.0, 10.0, 50.0, 60.0)]}
    write_sample(tmp_path / 'a.jpg', image, dets, 'x')
    write_sample(tmp_path / 'b.jpg', image, dets, 'x')
    assert (tmp_path / 'a.jpg').read_bytes() == (tmp_path / 'b.jpg').read_bytes()
    assert (tmp_path / 'a.jpg').read_bytes()[:3] == b'\xff\xd8\xff'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['a.jpg', 'b.jpg']


def test_grey_and_16_bit_images_and_png_output_work(tmp_path: Path) -> None:
    grey = np.arange(100 * 200, dtype=np.uint16).reshape(100, 200)
    write_sample(tmp_path / 'g.png', grey, {}, 'depth ünïcode title')
    out = cv2.imread(str(tmp_path / 'g.png'))
    assert out is not None
    assert out.shape == (100 + 2 * _BAR, 200, 3)
    assert (tmp_path / 'g.png').read_bytes()[:4] == b'\x89PNG'


def test_a_non_image_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match='HxWx3'):
        write_sample(tmp_path / 'x.jpg', np.zeros((4, 4, 2), np.uint8), {}, 'x')


def test_sample_paths_are_safe_file_names() -> None:
    assert sample_relpath(2, '/cam/front/image_raw') == 'samples/input2_cam_front_image_raw.jpg'
    assert sample_relpath(0, '<script>') == 'samples/input0_script.jpg'
    assert sample_relpath(0, '///') == 'samples/input0_topic.jpg'


def test_a_topic_longer_than_a_file_name_is_cut_and_told_apart_by_a_hash() -> None:
    first = sample_relpath(0, '/' + 'x' * 300)
    second = sample_relpath(0, '/' + 'x' * 299 + 'y')
    assert first != second
    assert len(first.removeprefix('samples/').encode()) < 255
    assert first.startswith('samples/input0_xxxx')
    assert sample_relpath(0, '/caméra/image') == 'samples/input0_cam_ra_image.jpg'
