"""The segmentation decoder: layouts from shapes, argmax and class ids, nearest map to the frame."""

from __future__ import annotations

import numpy as np
import pytest

from replaybench.detector.preprocess import Transform, geometry
from replaybench.detector.spec import Preprocess
from replaybench.errors import BackendError
from replaybench.segmentation.decoder import (
    SourceMapper,
    decode_labels,
    layout_from_shape,
    parse_layout,
    source_indices,
)


@pytest.mark.parametrize(
    ('shape', 'dtype', 'layout', 'classes', 'size'),
    [
        ((1, 5, 64, 80), 'float32', 'logits-nchw', 5, (80, 64)),
        ((1, 64, 80, 5), 'float32', 'logits-nhwc', 5, (80, 64)),
        ((1, 64, 80), 'int64', 'labels', None, (80, 64)),
        ((1, 1, 64, 80), 'int32', 'labels', None, (80, 64)),
        ((1, 64, 80, 1), 'int32', 'labels', None, (80, 64)),
        ((1, 64, 80), 'float32', 'labels', None, (80, 64)),
        ((1, 3, 32, 40), 'float32', 'logits-nchw', 3, (40, 32)),
    ],
)
def test_the_layout_of_an_output_is_read_from_its_shape_and_type(
    shape: tuple[int, ...], dtype: str, layout: str, classes: int | None, size: tuple[int, int]
) -> None:
    found, source = layout_from_shape(shape, dtype, input_size=(160, 128))
    assert (found.layout, found.num_classes, found.size, source) == (
        layout,
        classes,
        size,
        'shape',
    )


def test_a_square_score_output_is_placed_by_the_input_size_and_stride() -> None:
    # 64 classes on a 64x64 grid of a 256x256 input: only the stride tells the axes apart
    nhwc, _ = layout_from_shape((1, 64, 64, 80), 'float32', input_size=(256, 256))
    nchw, _ = layout_from_shape((1, 80, 64, 64), 'float32', input_size=(256, 256))
    assert (nhwc.layout, nchw.layout) == ('logits-nhwc', 'logits-nchw')


def test_an_output_that_cannot_be_told_apart_asks_for_the_flag() -> None:
    with pytest.raises(BackendError, match='--model-family'):
        layout_from_shape((1, 'c', 'h', 'w'), 'float32', input_size=(64, 64))


def test_a_declared_layout_overrides_the_shape_and_names_its_source() -> None:
    found, source = layout_from_shape(
        (1, 5, 64, 80), 'float32', input_size=(80, 64), declared='option:logits-nhwc'
    )
    assert (found.layout, found.num_classes, source) == ('logits-nhwc', 80, 'option')


def test_an_unknown_layout_or_a_wrong_rank_is_one_clear_error() -> None:
    with pytest.raises(BackendError, match='unknown segmentation layout'):
        parse_layout('yolox')
    with pytest.raises(BackendError, match='segmentation output is'):
        layout_from_shape((100, 6), 'float32')
    with pytest.raises(BackendError, match='needs a 4-D output'):
        layout_from_shape((1, 8, 8), 'float32', declared='metadata:logits-nchw')


def test_argmax_over_the_class_axis_gives_exact_labels_in_both_layouts() -> None:
    rng = np.random.default_rng(7)
    scores = rng.normal(size=(1, 4, 3, 5)).astype(np.float32)
    expected = np.zeros((3, 5), dtype=np.uint8)
    for y in range(3):
        for x in range(5):
            expected[y, x] = int(np.argmax(scores[0, :, y, x]))
    assert np.array_equal(decode_labels(scores, 'logits-nchw'), expected)
    nhwc = np.ascontiguousarray(scores.transpose(0, 2, 3, 1))
    assert np.array_equal(decode_labels(nhwc, 'logits-nhwc'), expected)


def test_ties_go_to_the_first_class() -> None:
    scores = np.zeros((1, 3, 1, 2), dtype=np.float32)
    scores[0, 2, 0, 1] = 1.0
    assert decode_labels(scores, 'logits-nchw').tolist() == [[0, 2]]


@pytest.mark.parametrize('shape', [(1, 2, 3), (1, 1, 2, 3), (1, 2, 3, 1)])
def test_class_id_outputs_of_every_shape_give_the_same_plane(shape: tuple[int, ...]) -> None:
    ids = np.array([[0, 1, 2], [3, 4, 255]], dtype=np.int64)
    assert decode_labels(ids.reshape(shape), 'labels').tolist() == ids.tolist()


def test_class_ids_outside_a_byte_are_refused() -> None:
    with pytest.raises(BackendError, match='class id 256'):
        decode_labels(np.array([[[0, 256]]], dtype=np.int32), 'labels')
    with pytest.raises(BackendError, match='class id -1'):
        decode_labels(np.array([[[-1, 0]]], dtype=np.int32), 'labels')
    with pytest.raises(BackendError, match='not whole class ids'):
        decode_labels(np.array([[[0.5, 0]]], dtype=np.float32), 'labels')


def test_a_stretched_output_maps_back_to_the_frame_pixel_for_pixel() -> None:
    # a 2x2 output of a 4x4 input stretched from an 8x4 frame: each output pixel is a 4x2 block
    pre = Preprocess(size=(4, 4), letterbox=False)
    *_, transform = geometry(8, 4, pre)
    labels = np.array([[1, 2], [3, 4]], dtype=np.uint8)
    mapped = SourceMapper((4, 4))(labels, transform)
    expected = np.array(
        [
            [1, 1, 1, 1, 2, 2, 2, 2],
            [1, 1, 1, 1, 2, 2, 2, 2],
            [3, 3, 3, 3, 4, 4, 4, 4],
            [3, 3, 3, 3, 4, 4, 4, 4],
        ],
        dtype=np.uint8,
    )
    assert mapped.dtype == np.uint8
    assert np.array_equal(mapped, expected)


def test_a_letterboxed_output_drops_the_padding_rows() -> None:
    # a 4x2 frame letterboxed (centre) into a 4x4 input: rows 1 and 2 of the output are the frame
    pre = Preprocess(size=(4, 4), letterbox=True, align='center')
    *_, transform = geometry(4, 2, pre)
    assert transform.pad_y == 1.0
    labels = np.array(
        [[9, 9, 9, 9], [1, 2, 3, 4], [5, 6, 7, 8], [9, 9, 9, 9]],
        dtype=np.uint8,
    )
    assert SourceMapper((4, 4))(labels, transform).tolist() == [[1, 2, 3, 4], [5, 6, 7, 8]]


def test_a_top_left_letterbox_and_an_upscale_map_each_source_pixel_to_its_centre() -> None:
    # a 3x2 frame into a 6x6 input top-left (scale 2): the frame fills rows 0..3 of the input;
    # the output is the input at stride 2 (3x3): source (x, y) -> output (x, y)
    pre = Preprocess(size=(6, 6), letterbox=True, align='topleft')
    *_, transform = geometry(3, 2, pre)
    labels = np.arange(9, dtype=np.uint8).reshape(3, 3)
    assert SourceMapper((6, 6))(labels, transform).tolist() == [[0, 1, 2], [3, 4, 5]]


def test_the_remap_agrees_with_numpy_indexing_on_odd_sizes() -> None:
    rng = np.random.default_rng(3)
    for src_w, src_h, in_size, stride, letterbox in [
        (641, 359, (320, 320), 4, True),
        (1920, 1080, (512, 288), 2, False),
        (33, 97, (64, 64), 1, True),
    ]:
        pre = Preprocess(size=in_size, letterbox=letterbox)
        *_, transform = geometry(src_w, src_h, pre)
        out_size = (in_size[0] // stride, in_size[1] // stride)
        labels = rng.integers(0, 256, size=(out_size[1], out_size[0]), dtype=np.uint8)
        cols, rows = source_indices(transform, in_size, out_size)
        expected = labels[rows[:, None], cols[None, :]]
        mapped = SourceMapper(in_size)(labels, transform)
        assert mapped.shape == (src_h, src_w)
        assert np.array_equal(mapped, expected)


def test_each_call_returns_a_fresh_array() -> None:
    mapper = SourceMapper((4, 4))
    transform = Transform(1.0, 0.0, 0.0, 4, 4)
    labels = np.ones((4, 4), dtype=np.uint8)
    first = mapper(labels, transform)
    second = mapper(labels * 2, transform)
    assert first is not second
    assert int(first[0, 0]) == 1


def test_the_plane_by_plane_argmax_equals_numpy_with_ties_and_nan() -> None:
    rng = np.random.default_rng(5)
    for classes in (2, 5, 19, 32):
        scores = rng.integers(-3, 3, size=(1, classes, 17, 23)).astype(np.float32)  # many ties
        expected = np.argmax(scores[0], axis=0).astype(np.uint8)
        assert np.array_equal(decode_labels(scores, 'logits-nchw'), expected)
    scores = rng.normal(size=(1, 4, 3, 3)).astype(np.float32)
    scores[0, 2, 1, 1] = np.nan
    assert decode_labels(scores, 'logits-nchw')[1, 1] == 2  # numpy: NaN is the largest
    assert np.array_equal(
        decode_labels(scores, 'logits-nchw'), np.argmax(scores[0], axis=0).astype(np.uint8)
    )
