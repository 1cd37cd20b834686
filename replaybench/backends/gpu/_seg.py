"""Segmentation models on the GPU engines of ``cuda`` / ``tensorrt``: which models are
segmentation models, and their pipeline.

A model is a segmentation model as ``onnx-seg`` reads it: ``--model-family`` one of
``logits-nchw`` / ``logits-nhwc`` / ``labels``; else the ``replaybench.seg_layout``
metadata; else (no ``replaybench.family`` metadata) the first output's shape: 4-D, or 3-D
with integer class ids or with axes 1-2 the input divided by a stride. Its spec is
``replaybench.segmentation.spec.load_seg_spec``'s, its output read by the shared decoder.

Per frame (``SegPipeline``): upload and preprocessing as for detectors (``DnnPipeline``);
``postprocess`` on the device: the argmax over classes of a score output, cast to uint8 (class
ids as they are for a ``labels`` output); ``d2h``: the model-sized uint8 (or integer) label
map; then on the host ``decode_labels`` (the checks of class ids) and the nearest-neighbour
``SourceMapper`` back to the frame, as ``onnx-seg`` does.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.backends.gpu._upload import DeviceInput
from replaybench.detector.decoders import NonfiniteTally
from replaybench.detector.spec import SPEC_KEYS
from replaybench.errors import BackendError
from replaybench.segmentation.decoder import (
    LAYOUTS,
    SourceMapper,
    decode_labels,
    parse_layout,
)
from replaybench.types import LabelMask

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    import numpy.typing as npt

    from replaybench.detector.preprocess import Transform
    from replaybench.segmentation.spec import SegModelSpec

__all__ = ['SegPipeline', 'cpu_session', 'is_segmentation', 'load_gpu_seg_spec', 'seg_facts']

Tensor = Any  # torch.Tensor
_MAX_CLASSES = 256
_INTEGER = ('int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64')


def cpu_session(path: Path) -> Any:
    """An onnxruntime session of ``path`` on the CPU, to read the model's inputs, outputs and
    metadata (the torch engine's and TensorRT's spec)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), options, providers=['CPUExecutionProvider'])
    except Exception as exc:  # onnxruntime raises several types for bad files
        msg = f'{path}: cannot load the ONNX model: {type(exc).__name__}: {exc}'
        raise BackendError(msg) from exc


def _dim(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 else None


def is_segmentation(session: Any, family: str | None) -> bool:
    """Whether the model of ``session`` is read as a segmentation model (module docstring)."""
    if family is not None:
        return family.strip().lower().replace('_', '-') in LAYOUTS
    meta = dict(session.get_modelmeta().custom_metadata_map)
    if meta.get('replaybench.seg_layout', '').strip():
        return True
    if meta.get('replaybench.family', '').strip():
        return False
    output = session.get_outputs()[0]
    shape = list(output.shape)
    if len(shape) == 4:
        return True
    if len(shape) != 3:
        return False
    if output.type.removeprefix('tensor(').removesuffix(')') in _INTEGER:
        return True
    inputs = session.get_inputs()
    in_shape = list(inputs[0].shape) if len(inputs) == 1 else []
    if len(in_shape) != 4:
        return False
    in_h, in_w, h, w = _dim(in_shape[2]), _dim(in_shape[3]), _dim(shape[1]), _dim(shape[2])
    if None in (in_h, in_w, h, w):
        return False
    assert in_h is not None
    assert in_w is not None
    assert h is not None
    assert w is not None
    return in_h % h == 0 and in_w % w == 0 and in_h // h == in_w // w


def load_gpu_seg_spec(
    path: Path,
    session: Any,
    family: str | None,
    labels: str | None,
    extra: Mapping[str, str],
) -> SegModelSpec:
    """``load_seg_spec`` with the layout from ``--model-family`` (None: metadata or shape)."""
    from replaybench.segmentation.spec import load_seg_spec

    layout = parse_layout(family, '--model-family') if family is not None else None
    overrides = {k: v for k, v in extra.items() if k in SPEC_KEYS}
    return load_seg_spec(path, session, layout=layout, labels=labels, overrides=overrides)


def seg_facts(spec: SegModelSpec) -> dict[str, Any]:
    """What ``info()`` records of a segmentation model (as ``onnx-seg``'s keys)."""
    scores = spec.layout.layout != 'labels'
    return {
        'task': 'segmentation',
        'conf': None,
        'iou': None,
        'max_det': None,
        'model_sha256': spec.sha256,
        'layout': spec.layout.layout,
        'layout_source': spec.layout_source,
        'input_size': list(spec.preprocess.size),
        'output': {'name': spec.output_name, 'shape': list(spec.output_shape)},
        'class_names': list(spec.class_names),
        'labels_source': spec.labels_source,
        'postprocess': 'argmax over classes on the device, uint8 class ids downloaded'
        if scores
        else 'class ids as output, downloaded',
        'resize': 'nearest, by source pixel centre (on the host)',
    }


class SegPipeline(DeviceInput):
    """Upload and preprocessing (``DeviceInput``); the label map as postprocessing."""

    def __init__(self, torch: Any, spec: SegModelSpec, device: Any, half: bool) -> None:
        super().__init__(torch, spec.preprocess, device, half)
        self.spec = spec
        #: No score threshold; nothing is left out for NaN or inf scores (argmax decides).
        self.conf: float | None = None
        self.nonfinite = NonfiniteTally()
        self._mapper = SourceMapper(spec.preprocess.size)

    def postprocess(self, outputs: Mapping[str, Tensor], transform: Transform) -> list[Tensor]:  # noqa: ARG002  the map back to the frame runs on the host
        """``[label map H x W]``: the argmax (uint8) of scores, the plane of class ids."""
        torch = self.torch
        out = outputs[self.spec.output_name]
        layout = self.spec.layout.layout
        if layout == 'labels':
            if out.ndim == 4:
                plane = out[0, 0] if int(out.shape[1]) == 1 else out[0, :, :, 0]
            elif out.ndim == 3:
                plane = out[0]
            else:
                msg = f'labels output has shape {list(out.shape)}; expected 3 or 4 axes'
                raise BackendError(msg)
            return [plane]
        axis = 1 if layout == 'logits-nchw' else 3
        if out.ndim != 4:
            msg = f'{layout} output has shape {list(out.shape)}; expected 4 axes'
            raise BackendError(msg)
        classes = int(out.shape[axis])
        if classes > _MAX_CLASSES:
            msg = f'the output has {classes} classes; a mask holds at most {_MAX_CLASSES}'
            raise BackendError(msg)
        return [torch.argmax(out[0], dim=axis - 1).to(torch.uint8)]

    def answer(
        self, arrays: Sequence[npt.NDArray[Any]], transform: Transform
    ) -> tuple[tuple[()], LabelMask]:
        """No detections, and the label mask in frame pixels (``decode_labels`` checks class
        ids of a ``labels`` output; ``SourceMapper`` maps back by nearest neighbour)."""
        plane = np.asarray(arrays[0])
        if plane.dtype == np.uint8 and self.spec.layout.layout != 'labels':
            labels = np.ascontiguousarray(plane)
        else:
            labels = decode_labels(plane[None], 'labels')
        return (), LabelMask(self._mapper(labels, transform), self.spec.class_names)
