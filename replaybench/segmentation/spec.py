"""An ONNX segmentation model as the segmentation backends use it: input, output layout,
preprocessing and class names.

The input is one ``[1, 3, H, W]`` float image as for detectors; the first output is the
segmentation output, its layout found by ``replaybench.segmentation.decoder.layout_from_shape``
(``--model-family``, else the ``replaybench.seg_layout`` metadata, else the shape).
Preprocessing defaults to the frame stretched to the input, RGB scaled by 1/255; the
``replaybench.*`` metadata and the backend options (``letterbox``, ``channel_order``,
``scale``, ``mean``, ``std``, ``pad_value``, ``letterbox_align``, ``size``) override it as for
detectors. Class names: ``--labels``, else the ``names`` metadata, else ``class0``, ... for
score outputs and the ids alone for class-id outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.detector.labels import resolve_labels
from replaybench.detector.spec import (
    DEFAULT_SIZE,
    SPEC_KEYS,
    Preprocess,
    file_sha256,
    preprocess_overrides,
)
from replaybench.errors import BackendError
from replaybench.segmentation.decoder import SegLayout, layout_from_shape

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = ['DEFAULT_SEG_MODEL', 'SegModelSpec', 'load_seg_spec']

#: The bundled segmentation model (training/train_seg.py).
DEFAULT_SEG_MODEL = Path(__file__).resolve().parents[1] / 'models' / 'blobs_seg.onnx'

_PRE_KEYS = tuple(k for k in SPEC_KEYS if k != 'size')
_ONNX_TYPES = {
    'tensor(float)': 'float32',
    'tensor(float16)': 'float16',
    'tensor(double)': 'float64',
    'tensor(int64)': 'int64',
    'tensor(int32)': 'int32',
    'tensor(uint8)': 'uint8',
    'tensor(int8)': 'int8',
    'tensor(uint16)': 'uint16',
    'tensor(int16)': 'int16',
}


@dataclass(frozen=True, slots=True)
class SegModelSpec:
    """What ``load_seg_spec`` read: ``size`` of the input is ``preprocess.size``."""

    path: Path
    sha256: str
    input_name: str
    output_name: str
    layout: SegLayout
    layout_source: str
    preprocess: Preprocess
    class_names: tuple[str, ...]
    labels_source: str
    precision: str
    input_shape: tuple[int | str | None, ...] = ()
    output_shape: tuple[int | str | None, ...] = ()
    metadata: Mapping[str, str] = field(default_factory=dict)

    @property
    def output_names(self) -> tuple[str, ...]:
        """The output an engine binds (the segmentation output), as ``ModelSpec``'s."""
        return (self.output_name,)


def _dim(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 else None


def _shape(value: Any) -> tuple[int | str | None, ...]:
    return tuple(d if isinstance(d, int | str) else None for d in value)


def _size_option(text: str) -> tuple[int, int]:
    import re

    match = re.fullmatch(r'\s*(\d+)\s*(?:[xX]\s*(\d+)\s*)?', text)
    if match is None or int(match[1]) <= 0 or (match[2] is not None and int(match[2]) <= 0):
        msg = f'option size must be W or WxH in pixels, got {text!r}'
        raise BackendError(msg)
    width = int(match[1])
    return (width, int(match[2]) if match[2] is not None else width)


def load_seg_spec(
    path: str | Path,
    session: Any,
    *,
    layout: str | None = None,
    labels: str | None = None,
    overrides: Mapping[str, str] | None = None,
) -> SegModelSpec:
    """Read a segmentation model from its open onnxruntime ``session``; ``BackendError``
    saying what does not fit."""
    path = Path(path)
    where = str(path)
    overrides = dict(overrides or {})
    inputs = session.get_inputs()
    if len(inputs) != 1:
        msg = f'{where}: expected one image input, the model has {len(inputs)}'
        raise BackendError(msg)
    inp = inputs[0]
    input_shape = _shape(inp.shape)
    if inp.type not in ('tensor(float)', 'tensor(float16)'):
        msg = f'{where}: input type {inp.type} is not supported (float32 or float16 inputs only)'
        raise BackendError(msg)
    if len(input_shape) != 4 or _dim(input_shape[1]) not in (None, 3):
        msg = f'{where}: input {inp.name!r} has shape {list(input_shape)}; expected [1, 3, H, W]'
        raise BackendError(msg)
    h, w = _dim(input_shape[2]), _dim(input_shape[3])
    size = (w, h) if w is not None and h is not None else None
    if 'size' in overrides:
        asked = _size_option(overrides['size'])
        if size is not None and asked != size:
            msg = f'{where}: option size {asked[0]}x{asked[1]} differs from the input {w}x{h}'
            raise BackendError(msg)
        size = asked
    if size is None:
        size = (w or h or DEFAULT_SIZE, h or w or DEFAULT_SIZE)
    meta = dict(session.get_modelmeta().custom_metadata_map)
    output = session.get_outputs()[0]
    out_shape = _shape(output.shape)
    dtype = _ONNX_TYPES.get(output.type, output.type)
    if layout is not None:
        declared: str | None = f'option:{layout}'
    elif meta.get('replaybench.seg_layout', '').strip():
        declared = f'metadata:{meta["replaybench.seg_layout"]}'
    else:
        declared = None
    found, source = layout_from_shape(
        out_shape, dtype, input_size=size, declared=declared, where=f'{where}: output {output.name}'
    )
    pre = Preprocess(size=size, letterbox=False, channel_order='rgb', scale=1.0 / 255.0)
    meta_pre = {k: meta[f'replaybench.{k}'] for k in _PRE_KEYS if f'replaybench.{k}' in meta}
    pre = preprocess_overrides(pre, meta_pre, f'{where} metadata')
    pre = preprocess_overrides(
        pre, {k: v for k, v in overrides.items() if k in _PRE_KEYS}, 'backend options'
    )
    try:
        class_names, labels_source = resolve_labels(labels, meta.get('names'), found.num_classes)
    except BackendError as exc:
        msg = f'{where}: {exc}'
        raise BackendError(msg) from exc
    return SegModelSpec(
        path=path,
        sha256=file_sha256(path),
        input_name=inp.name,
        output_name=output.name,
        layout=found,
        layout_source=source,
        preprocess=pre,
        class_names=class_names,
        labels_source=labels_source,
        precision='fp16' if inp.type == 'tensor(float16)' else 'fp32',
        input_shape=input_shape,
        output_shape=out_shape,
        metadata=meta,
    )
