"""Letterbox geometry, the input tensor, and boxes mapped back to source pixels."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from replaybench.detector.preprocess import (
    Letterboxer,
    Transform,
    boxes_to_source,
    geometry,
    letterbox,
)
from replaybench.detector.spec import Preprocess, default_preprocess
from replaybench.errors import BackendError

GREY = 90


def _scene(width: int, height: int, rect: tuple[int, int, int, int]) -> np.ndarray:
    """Grey BGR image with a pure red rectangle covering [x0, x1) x [y0, y1)."""
    image = np.full((height, width, 3), GREY, np.uint8)
    x0, y0, x1, y1 = rect
    image[y0:y1, x0:x1] = (0, 0, 255)
    return image


def _found_box(tensor: np.ndarray, order: str) -> np.ndarray:
    """Bounding box (model pixels, x1/y1 exclusive) of pixels that are mostly red."""
    red = tensor[0, 0 if order == 'rgb' else 2]
    blue = tensor[0, 2 if order == 'rgb' else 0]
    ys, xs = np.nonzero((red - blue) > 0.5 * (red.max() - blue.min()))
    return np.array([[xs.min(), ys.min(), xs.max() + 1, ys.max() + 1]], np.float32)


@pytest.mark.parametrize(
    ('src', 'size', 'align', 'expected'),
    [
        ((640, 480), (416, 416), 'center', (416, 312, 0, 52)),
        ((640, 480), (416, 416), 'topleft', (416, 312, 0, 0)),
        ((480, 640), (416, 416), 'center', (312, 416, 52, 0)),
        ((512, 512), (416, 416), 'topleft', (416, 416, 0, 0)),
        ((100, 50), (64, 32), 'center', (64, 32, 0, 0)),
        ((101, 20), (64, 64), 'center', (64, 13, 0, 25)),
    ],
)
def test_geometry_fits_the_frame_inside_the_input(src, size, align, expected):
    pre = Preprocess(size=size, align=align)
    new_w, new_h, left, top, transform = geometry(src[0], src[1], pre)
    assert (new_w, new_h, left, top) == expected
    assert transform.scale == pytest.approx(min(size[0] / src[0], size[1] / src[1]))
    assert (transform.pad_x, transform.pad_y) == (left, top)
    assert (transform.src_w, transform.src_h) == src


@pytest.mark.parametrize('align', ['center', 'topleft'])
@pytest.mark.parametrize(
    ('src', 'rect'),
    [
        ((300, 200), (60, 40, 180, 120)),  # landscape
        ((200, 300), (20, 150, 140, 290)),  # portrait
        ((333, 97), (10, 10, 320, 60)),  # odd, very wide
    ],
)
def test_a_box_found_in_model_pixels_maps_back_to_its_source_pixels(align, src, rect):
    pre = Preprocess(size=(160, 128), align=align, channel_order='rgb')
    width, height = src
    tensor, transform = letterbox(_scene(width, height, rect), 'bgr8', pre)
    found = _found_box(tensor, 'rgb')
    back = boxes_to_source(found, transform)[0]
    # resizing smears the edges by at most one model pixel = 1 / scale source pixels
    tolerance = 1.0 / transform.scale + 0.5
    np.testing.assert_allclose(back, rect, atol=tolerance)
    if align == 'topleft':
        assert transform.pad_x == transform.pad_y == 0


def test_a_stretched_input_maps_each_axis_with_its_own_scale():
    pre = Preprocess(size=(160, 128), letterbox=False)
    rect = (60, 40, 180, 120)
    tensor, transform = letterbox(_scene(300, 200, rect), 'bgr8', pre)
    assert transform.scale == pytest.approx(160 / 300)
    assert transform.scale_y == pytest.approx(128 / 200)
    back = boxes_to_source(_found_box(tensor, 'rgb'), transform)[0]
    np.testing.assert_allclose(back, rect, atol=2.5)


def test_boxes_to_source_inverts_the_transform_exactly_and_clips():
    t = Transform(0.5, 10.0, 4.0, 100, 50)
    boxes = np.array([[10, 4, 60, 29], [0, 0, 70, 40]], np.float32)
    out = boxes_to_source(boxes, t)
    assert out.tolist() == [[0, 0, 100, 50], [0, 0, 100, 50]]
    t = Transform(0.5, 10.0, 4.0, 400, 400)
    assert boxes_to_source(boxes, t).tolist() == [[0, 0, 100, 50], [0, 0, 120, 72]]


def test_pad_pixels_hold_the_pad_value_times_the_scale():
    pre = default_preprocess('yolov8', (64, 64))
    image = np.full((32, 64, 3), 200, np.uint8)
    tensor, transform = letterbox(image, 'rgb8', pre)
    assert transform.pad_y == 16
    np.testing.assert_allclose(tensor[0, :, :16], 114 / 255, rtol=1e-6)
    np.testing.assert_allclose(tensor[0, :, 48:], 114 / 255, rtol=1e-6)
    np.testing.assert_allclose(tensor[0, :, 16:48], 200 / 255, rtol=1e-6)


def test_yolox_defaults_give_raw_bgr_values_padded_at_the_bottom_right():
    pre = default_preprocess('yolox', (64, 64))
    image = np.zeros((32, 48, 3), np.uint8)
    image[...] = (10, 20, 30)  # BGR
    tensor, _ = letterbox(image, 'bgr8', pre)
    assert tensor.dtype == np.float32
    assert tensor.flags.c_contiguous
    assert tensor.shape == (1, 3, 64, 64)
    assert tensor[0, :, 0, 0].tolist() == [10, 20, 30]
    assert tensor[0, :, 63, 63].tolist() == [114, 114, 114]
    # 48x32 scaled by 4/3 -> 64x43: the width is filled, the pad is the rows below
    assert tensor[0, :, 0, 63].tolist() == [10, 20, 30]
    assert tensor[0, :, 42, 0].tolist() == [10, 20, 30]
    assert tensor[0, :, 43, 0].tolist() == [114, 114, 114]


def test_rgb_and_bgr_frames_of_the_same_scene_give_the_same_tensor():
    image = _scene(120, 90, (10, 10, 50, 40))
    image[60:, 60:] = (255, 0, 0)  # blue
    for order in ('rgb', 'bgr'):
        pre = Preprocess(size=(64, 64), channel_order=order)
        from_bgr = letterbox(image, 'bgr8', pre)[0].copy()
        from_rgb = letterbox(cv2.cvtColor(image, cv2.COLOR_BGR2RGB), 'rgb8', pre)[0]
        from_rgba = letterbox(cv2.cvtColor(image, cv2.COLOR_BGR2RGBA), 'rgba8', pre)[0]
        from_bgra = letterbox(cv2.cvtColor(image, cv2.COLOR_BGR2BGRA), 'bgra8', pre)[0]
        np.testing.assert_array_equal(from_bgr, from_rgb)
        np.testing.assert_array_equal(from_bgr, from_rgba)
        np.testing.assert_array_equal(from_bgr, from_bgra)
    rgb = letterbox(image, 'bgr8', Preprocess(size=(64, 64), channel_order='rgb'))[0]
    assert rgb[0, 0, 20, 15] == pytest.approx(1.0)  # red in channel 0
    assert rgb[0, 2, 50, 50] == pytest.approx(1.0)  # blue in channel 2


def test_mean_and_std_are_applied_per_channel_after_scaling():
    pre = Preprocess(
        size=(8, 8),
        channel_order='rgb',
        scale=1 / 255,
        mean=(0.485, 0.456, 0.406),
        std=(0.229, 0.224, 0.225),
    )
    image = np.zeros((8, 8, 3), np.uint8)
    image[...] = (51, 102, 204)  # RGB
    tensor, _ = letterbox(image, 'rgb8', pre)
    expected = [
        (51 / 255 - 0.485) / 0.229,
        (102 / 255 - 0.456) / 0.224,
        (204 / 255 - 0.406) / 0.225,
    ]
    np.testing.assert_allclose(tensor[0, :, 3, 3], expected, rtol=1e-5)


def test_mono8_is_copied_into_all_three_channels():
    image = np.arange(64 * 48, dtype=np.uint32).reshape(48, 64).astype(np.uint8)
    tensor, _ = letterbox(image, 'mono8', default_preprocess('yolov5', (64, 64)))
    np.testing.assert_array_equal(tensor[0, 0], tensor[0, 1])
    np.testing.assert_array_equal(tensor[0, 0], tensor[0, 2])
    as_bgr = letterbox(
        cv2.cvtColor(image, cv2.COLOR_GRAY2BGR), 'bgr8', default_preprocess('yolov5', (64, 64))
    )[0]
    np.testing.assert_array_equal(tensor, as_bgr)


def test_mono16_is_scaled_to_eight_bits_by_the_frame_maximum():
    image = np.zeros((16, 16), np.uint16)
    image[4:8, 4:8] = 4000
    image[0, 0] = 8000
    tensor, _ = letterbox(image, 'mono16', Preprocess(size=(16, 16), scale=1.0))
    assert tensor[0, 0, 0, 0] == 255
    assert tensor[0, 1, 5, 5] == 128  # round(4000 * 255 / 8000)
    assert tensor[0, 2, 12, 12] == 0


def test_the_letterboxer_reuses_its_tensor_and_adapts_to_new_frame_sizes():
    box = Letterboxer(Preprocess(size=(32, 32)))
    first, t1 = box(np.full((16, 32, 3), 255, np.uint8), 'rgb8')
    second, t2 = box(np.full((32, 16, 3), 0, np.uint8), 'rgb8')
    assert first is second
    assert (t1.pad_y, t2.pad_x) == (8, 8)
    assert second[0, 0, 16, 0] == pytest.approx(114 / 255)  # left pad of the new size
    assert second[0, 0, 16, 16] == 0.0


def test_fp16_models_get_a_float16_tensor():
    tensor, _ = Letterboxer(Preprocess(size=(16, 16)), 'fp16')(
        np.full((16, 16, 3), 255, np.uint8), 'bgr8'
    )
    assert tensor.dtype == np.float16
    assert float(tensor[0, 0, 0, 0]) == 1.0


def test_wrong_pixel_layouts_are_refused_with_the_shape():
    with pytest.raises(BackendError, match=r'3-channel uint8 image for rgb8, got shape \(4, 4\)'):
        letterbox(np.zeros((4, 4), np.uint8), 'rgb8', Preprocess(size=(8, 8)))
    with pytest.raises(BackendError, match='empty'):
        letterbox(np.zeros((0, 4, 3), np.uint8), 'rgb8', Preprocess(size=(8, 8)))
