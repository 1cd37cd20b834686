"""onnx-seg through a real onnxruntime session: every output layout, stride and resize mode."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
from detector.onnxgraph import Output, write_model

from replaybench.backends import BackendOptions, get_backend
from replaybench.backends.onnx_seg import OnnxSegBackend
from replaybench.detector.preprocess import geometry
from replaybench.detector.spec import Preprocess
from replaybench.errors import BackendError
from replaybench.segmentation.decoder import source_indices
from replaybench.types import Frame

if TYPE_CHECKING:
    from pathlib import Path

IN_W, IN_H = 32, 24


def _frame(width: int, height: int) -> Frame:
    image = np.full((height, width, 3), 100, np.uint8)
    return Frame('/camera/image_raw', 3, 0, 0, 'cam', image, 'rgb8', 'rgb8')


def _expected(plane: np.ndarray, width: int, height: int, *, letterbox: bool) -> np.ndarray:
    pre = Preprocess(size=(IN_W, IN_H), letterbox=letterbox)
    *_, transform = geometry(width, height, pre)
    cols, rows = source_indices(transform, (IN_W, IN_H), (plane.shape[1], plane.shape[0]))
    return plane[rows[:, None], cols[None, :]]


def _scores(classes: int, out_h: int, out_w: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(classes * 100 + out_w)
    scores = rng.normal(size=(1, classes, out_h, out_w)).astype(np.float32)
    return scores, scores[0].argmax(axis=0).astype(np.uint8)


@pytest.mark.parametrize('stride', [1, 2, 4])
@pytest.mark.parametrize('nhwc', [False, True])
def test_score_outputs_give_the_argmax_mapped_to_the_frame(
    tmp_path: Path, stride: int, nhwc: bool
) -> None:
    scores, plane = _scores(5, IN_H // stride, IN_W // stride)
    value = np.ascontiguousarray(scores.transpose(0, 2, 3, 1)) if nhwc else scores
    model = write_model(
        tmp_path / 'seg.onnx',
        [Output('logits', value)],
        input_shape=(1, 3, IN_H, IN_W),
        metadata={'names': 'bg,a,b,c,d'},
    )
    backend = OnnxSegBackend(BackendOptions(model=model, threads=1))
    result = backend.detect(_frame(64, 48))
    assert result.detections == ()
    assert result.mask is not None
    assert result.mask.class_names == ('bg', 'a', 'b', 'c', 'd')
    assert np.array_equal(result.mask.labels, _expected(plane, 64, 48, letterbox=False))
    info = backend.info()
    assert info['layout'] == ('logits-nhwc' if nhwc else 'logits-nchw')
    assert info['layout_source'] == 'shape'
    stages = result.stages
    assert stages.preprocess_ns is not None
    assert stages.infer_ns is not None
    assert stages.postprocess_ns is not None


@pytest.mark.parametrize('shape', ['nhw', 'n1hw', 'nhw1'])
def test_class_id_outputs_in_every_tao_shape_map_to_the_frame(tmp_path: Path, shape: str) -> None:
    ids = (np.arange(IN_H * IN_W, dtype=np.int64).reshape(IN_H, IN_W) * 7) % 6
    value = {'nhw': ids[None], 'n1hw': ids[None, None], 'nhw1': ids[None, :, :, None]}[shape]
    model = write_model(
        tmp_path / 'tao.onnx', [Output('argmax_1', value.astype(np.int32))],
        input_shape=(1, 3, IN_H, IN_W),
    )  # fmt: skip
    backend = OnnxSegBackend(BackendOptions(model=model, threads=1))
    mask = backend.detect(_frame(45, 30)).mask
    assert mask is not None
    assert mask.class_names == ()  # ids only: the model names no classes
    assert np.array_equal(mask.labels, _expected(ids.astype(np.uint8), 45, 30, letterbox=False))
    assert backend.info()['layout'] == 'labels'


def test_a_letterboxed_model_drops_its_padding(tmp_path: Path) -> None:
    scores, plane = _scores(3, IN_H, IN_W)
    model = write_model(
        tmp_path / 'lb.onnx',
        [Output('out', scores)],
        input_shape=(1, 3, IN_H, IN_W),
        metadata={'replaybench.letterbox': 'true'},
    )
    mask = OnnxSegBackend(BackendOptions(model=model)).detect(_frame(40, 10)).mask
    assert mask is not None
    assert mask.labels.shape == (10, 40)
    assert np.array_equal(mask.labels, _expected(plane, 40, 10, letterbox=True))


def test_the_layout_flag_overrides_the_shape(tmp_path: Path) -> None:
    # [1, 6, 6, 8] of a 8x6 input: read from the shape as [1, C, H, W]; the flag says NHWC
    value = np.random.default_rng(1).normal(size=(1, 6, 6, 8)).astype(np.float32)
    model = write_model(tmp_path / 'sq.onnx', [Output('out', value)], input_shape=(1, 3, 6, 8))
    by_shape = OnnxSegBackend(BackendOptions(model=model))
    flagged = OnnxSegBackend(BackendOptions(model=model, model_family='logits-nhwc'))
    by_shape.open()
    flagged.open()
    assert by_shape.info()['layout'] == 'logits-nchw'
    assert (flagged.info()['layout'], flagged.info()['layout_source']) == ('logits-nhwc', 'option')


def test_bad_models_and_options_are_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(BackendError, match='unknown segmentation layout'):
        OnnxSegBackend(BackendOptions(model_family='yolox'))
    with pytest.raises(BackendError, match="onnx-seg: unknown option 'conf'"):
        OnnxSegBackend(BackendOptions(extra={'conf': '0.5'}))
    with pytest.raises(BackendError, match='not found'):
        OnnxSegBackend(BackendOptions(model=tmp_path / 'missing.onnx')).open()
    flat = write_model(tmp_path / 'flat.onnx', [Output('out', np.zeros((1, 100), np.float32))])
    with pytest.raises(BackendError, match=r'onnx-seg: .*a segmentation output is \[1, C, H, W\]'):
        OnnxSegBackend(BackendOptions(model=flat)).open()
    wide = write_model(
        tmp_path / 'ids.onnx', [Output('ids', np.full((1, 4, 4), 300, np.int32))],
        input_shape=(1, 3, 4, 4),
    )  # fmt: skip
    with pytest.raises(BackendError, match='class id 300'):
        OnnxSegBackend(BackendOptions(model=wide)).detect(_frame(4, 4))


def test_the_backend_is_registered() -> None:
    assert get_backend('onnx-seg') is OnnxSegBackend
