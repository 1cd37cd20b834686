"""Segmentation models through the ``cuda`` backend's engines, with CPU stand-ins.

These tests do NOT exercise a GPU: torch on the CPU stands in for torch on CUDA and
onnxruntime's CPU provider for its CUDA provider (``gpufakes``). The bundled segmentation model,
rewritten into every output layout (scores NCHW / NHWC, class ids ``[1, H, W]``,
``[1, 1, H, W]``, ``[1, H, W, 1]``), runs on frames of a fixture bag written with ground-truth
masks; its masks must equal ``onnx-seg``'s pixel for pixel.
"""

from __future__ import annotations

import importlib.util
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from backends.gpu.gpufakes import GPU_A, fake_gpu_build, torch_on_the_cpu

from replaybench.backends.base import BackendOptions, backend_task
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.onnx_seg import OnnxSegBackend
from replaybench.errors import BackendError
from replaybench.fixtures.masks import MASK_CLASS_NAMES
from replaybench.fixtures.writer import write_mcap
from replaybench.segmentation.spec import DEFAULT_SEG_MODEL
from replaybench.types import Frame

if TYPE_CHECKING:
    from pathlib import Path

#: layout name -> (nodes appended after ``logits``, the ``replaybench.seg_layout`` metadata)
LAYOUTS: dict[str, tuple[list[tuple[str, dict[str, Any]]], str | None]] = {
    'logits-nchw': ([], 'logits-nchw'),
    'logits-nhwc': ([('Transpose', {'perm': [0, 2, 3, 1]})], None),
    'labels-nhw': ([('ArgMax', {'axis': 1, 'keepdims': 0})], None),
    'labels-n1hw': ([('ArgMax', {'axis': 1, 'keepdims': 1})], None),
    'labels-nhw1': (
        [('Transpose', {'perm': [0, 2, 3, 1]}), ('ArgMax', {'axis': 3, 'keepdims': 1})],
        None,
    ),
}
EXPECTED_LAYOUT = {
    'logits-nchw': ('logits-nchw', 'metadata'),
    'logits-nhwc': ('logits-nhwc', 'shape'),
    'labels-nhw': ('labels', 'shape'),
    'labels-n1hw': ('labels', 'shape'),
    'labels-nhw1': ('labels', 'shape'),
}


def _needs_onnx2torch() -> Any:
    torch = pytest.importorskip('torch')
    pytest.importorskip('onnx')
    if importlib.util.find_spec('onnx2torch') is None:
        pytest.skip('onnx2torch is not installed (make install)')
    return torch


def _variant(tmp_path: Path, layout: str) -> Path:
    """The bundled model with ``layout``'s nodes after its scores, written as ONNX."""
    onnx = pytest.importorskip('onnx')
    helper = onnx.helper
    proto = onnx.load(str(DEFAULT_SEG_MODEL))
    nodes, meta = LAYOUTS[layout]
    (output,) = proto.graph.output
    name = output.name
    for index, (op, attrs) in enumerate(nodes):
        out = f'seg_{index}'
        proto.graph.node.append(helper.make_node(op, [name], [out], **attrs))
        name = out
    if nodes:
        del proto.graph.output[:]
        proto.graph.output.append(helper.make_empty_tensor_value_info(name))
        proto = onnx.shape_inference.infer_shapes(proto)
        (inferred,) = [v for v in proto.graph.value_info if v.name == name]
        del proto.graph.output[:]
        proto.graph.output.append(inferred)
    props = {p.key: p.value for p in proto.metadata_props}
    props.pop('replaybench.seg_layout')
    if meta is not None:
        props['replaybench.seg_layout'] = meta
    del proto.metadata_props[:]
    for key, value in props.items():
        proto.metadata_props.add(key=key, value=value)
    path = tmp_path / f'{layout}.onnx'
    onnx.save(proto, str(path))
    return path


@pytest.fixture(scope='module')
def frames(tmp_path_factory: pytest.TempPathFactory) -> list[Frame]:
    """Frames of a fixture bag written with ground-truth masks (``fixtures --masks``)."""
    from replaybench.decode import decode_image, message_kind
    from replaybench.sources import open_source

    bag = write_mcap(tmp_path_factory.mktemp('seg') / 'seg.mcap', 4, masks=True)
    found = []
    with open_source(bag) as source:
        for raw in source.messages():
            if raw.topic != '/camera/image_raw' or message_kind(raw.msgtype) != 'image':
                continue
            img = decode_image(raw)
            found.append(Frame(raw.topic, raw.seq, 0, 0, '', np.array(img.image), img.encoding, ''))
    assert len(found) == 4
    return found


def _masks(backend: Any, frames: list[Frame]) -> tuple[list[Any], dict[str, Any]]:
    backend.open()
    try:
        results = [backend.detect(frame) for frame in frames]
        info = backend.info()
    finally:
        backend.close()
    return results, info


@pytest.mark.parametrize('layout', list(LAYOUTS))
def test_the_torch_engine_gives_onnx_segs_masks_in_every_layout(
    monkeypatch, tmp_path, frames, driver, layout
):
    torch = _needs_onnx2torch()
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    model = _variant(tmp_path, layout)

    results, info = _masks(CudaBackend(BackendOptions(model=model, engine='torch')), frames)
    expected, _ = _masks(OnnxSegBackend(BackendOptions(model=model, threads=1)), frames)

    for ours, theirs, frame in zip(results, expected, frames, strict=True):
        assert ours.detections == ()
        assert ours.mask is not None
        assert theirs.mask is not None
        assert ours.mask.labels.shape == frame.image.shape[:2]
        assert ours.mask.labels.dtype == np.uint8
        assert np.array_equal(ours.mask.labels, theirs.mask.labels)
        assert ours.mask.class_names == tuple(MASK_CLASS_NAMES)
        for value in (ours.stages.h2d_ns, ours.stages.postprocess_ns, ours.stages.d2h_ns):
            assert value is not None
            assert value >= 0
    # more than one class is found: the masks are not trivially equal
    assert len(np.unique(np.concatenate([r.mask.labels.ravel() for r in results]))) >= 3
    assert (info['task'], info['engine']) == ('segmentation', 'torch')
    assert (info['layout'], info['layout_source']) == EXPECTED_LAYOUT[layout]
    assert info['class_names'] == list(MASK_CLASS_NAMES)


def test_the_ort_engine_binds_the_segmentation_output_and_gives_onnx_segs_masks(
    monkeypatch, frames, driver
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    torch_on_the_cpu(monkeypatch, torch)

    options = BackendOptions(engine='ort', model=DEFAULT_SEG_MODEL)
    results, info = _masks(CudaBackend(options), frames[:2])
    expected, _ = _masks(OnnxSegBackend(BackendOptions(threads=1)), frames[:2])
    for ours, theirs in zip(results, expected, strict=True):
        assert ours.mask is not None
        assert theirs.mask is not None
        assert np.array_equal(ours.mask.labels, theirs.mask.labels)
    assert info['engine'] == 'ort'
    assert info['providers'][0] == 'CUDAExecutionProvider'
    assert (info['layout'], info['layout_source']) == ('logits-nchw', 'metadata')


def test_cuda_declares_the_task_of_the_model_it_opened(monkeypatch, driver):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    torch_on_the_cpu(monkeypatch, torch)

    backend = CudaBackend(BackendOptions(engine='ort', model=DEFAULT_SEG_MODEL))
    assert backend_task(backend, 0) == 'detections'  # nothing read of the model yet
    backend.open()
    try:
        assert backend_task(backend, 0) == 'segmentation'
    finally:
        backend.close()


def test_model_family_picks_the_segmentation_layout_as_onnx_seg_does(
    monkeypatch, tmp_path, frames, driver
):
    torch = _needs_onnx2torch()
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    model = _variant(tmp_path, 'logits-nhwc')

    options = BackendOptions(model=model, engine='torch', model_family='logits-nhwc')
    results, info = _masks(CudaBackend(options), frames[:1])
    assert results[0].mask is not None
    assert (info['layout'], info['layout_source']) == ('logits-nhwc', 'option')
    wrong = BackendOptions(model=model, engine='torch', model_family='labels')
    with pytest.raises(BackendError, match=r'labels need a 1 at axis 1 or 3'):
        CudaBackend(wrong).open()


def test_a_detection_model_family_still_reads_the_model_as_a_detector(tiny_model):
    backend = CudaBackend(BackendOptions(model=tiny_model, model_family='yolov8'))
    assert backend._load_spec(None).class_names == ('a', 'b')
    with pytest.raises(BackendError, match=r'unknown --model-family .*logits-nchw'):
        CudaBackend(BackendOptions(model=tiny_model, model_family='unet'))
