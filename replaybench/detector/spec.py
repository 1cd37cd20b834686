"""What a detection model is: its input, output layout (family), preprocessing and classes.

``load_model_spec`` reads an ONNX graph with onnxruntime (the ``onnx`` package is not needed):
input name, shape and dtype, output names and shapes, and the ``metadata_props``. The family
(output layout) comes from, in this order: the ``family`` argument (``--model-family``), the
``replaybench.family`` metadata key, the output shapes (see ``family_from_shapes``), and for
the one ambiguous shape, a probe inference (see ``looks_raw_grid``).
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from replaybench.detector.labels import resolve_labels
from replaybench.errors import BackendError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy as np
    import numpy.typing as npt

__all__ = [
    'AMBIGUOUS',
    'DEFAULT_CONF',
    'DEFAULT_IOU',
    'DEFAULT_MODEL',
    'FAMILIES',
    'SPEC_KEYS',
    'STRIDES',
    'ModelSpec',
    'Preprocess',
    'default_preprocess',
    'family_from_shapes',
    'file_sha256',
    'grid_points',
    'load_model_spec',
    'looks_raw_grid',
    'preprocess_overrides',
]

FAMILIES = ('yolox', 'yolov5', 'yolov8', 'nms')
#: ``family_from_shapes`` result for ``[1, N, 5+C]`` with N = grid points: YOLOX or YOLOv5.
AMBIGUOUS = 'yolox|yolov5'
#: Strides of the three YOLO detection heads.
STRIDES = (8, 16, 32)
#: The bundled model (package data); it may be absent from a source checkout.
DEFAULT_MODEL = Path(__file__).resolve().parents[1] / 'models' / 'blobs.onnx'
#: Score threshold per family when ``--conf`` is not given (YOLOX's demo uses 0.3).
DEFAULT_CONF: dict[str, float] = {'yolox': 0.3, 'yolov5': 0.25, 'yolov8': 0.25, 'nms': 0.25}
DEFAULT_IOU = 0.45
#: Input side used when the model's input height / width are dynamic and nothing says more.
DEFAULT_SIZE = 640

ChannelOrder = Literal['bgr', 'rgb']
Align = Literal['topleft', 'center']


@dataclass(frozen=True, slots=True)
class Preprocess:
    """How a frame becomes the model's input tensor.

    ``size`` is (width, height) of the input. ``letterbox``: keep the aspect ratio and pad with
    ``pad_value`` (aligned ``topleft`` or ``center``); False stretches to ``size``. Each input
    value is ``(pixel * scale - mean[c]) / std[c]`` in ``channel_order``.
    """

    size: tuple[int, int]
    letterbox: bool = True
    pad_value: int = 114
    channel_order: ChannelOrder = 'rgb'
    scale: float = 1.0 / 255.0
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    align: Align = 'center'


@dataclass(frozen=True, slots=True)
class ModelSpec:
    """An ONNX detection model as the detector pipeline uses it.

    ``output_names`` are the outputs to run, primary first (YOLO families run one output).
    ``class_names`` may be empty for ``nms`` models without names (labels are then the class
    indices). ``precision`` is ``fp32`` or ``fp16`` from the input dtype.
    """

    path: Path
    sha256: str
    input_name: str
    output_names: tuple[str, ...]
    family: str
    preprocess: Preprocess
    class_names: tuple[str, ...]
    precision: str
    family_source: str = ''
    labels_source: str = ''
    input_shape: tuple[int | str | None, ...] = ()
    output_shapes: tuple[tuple[int | str | None, ...], ...] = ()
    metadata: Mapping[str, str] = field(default_factory=dict)

    @property
    def num_classes(self) -> int:
        return len(self.class_names)


def default_preprocess(family: str, size: tuple[int, int]) -> Preprocess:
    """Family defaults: YOLOX raw BGR 0-255 top-left; the others RGB / 255 centred; pad 114."""
    if family == 'yolox':
        return Preprocess(size=size, channel_order='bgr', scale=1.0, align='topleft')
    return Preprocess(size=size, channel_order='rgb', scale=1.0 / 255.0, align='center')


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open('rb') as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def grid_points(size: tuple[int, int], strides: Sequence[int] = STRIDES) -> int:
    """Anchor points of a YOLO head for an input of ``size`` (w, h): sum of (w/s)*(h/s)."""
    return sum((size[0] // s) * (size[1] // s) for s in strides)


def _dim(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 else None


def family_from_shapes(
    shapes: Sequence[Sequence[int | str | None]],
    names: Sequence[str],
    size: tuple[int, int],
) -> str | None:
    """The family the output shapes point to, ``AMBIGUOUS``, or None when they say nothing.

    With G = ``grid_points(size)`` (3549 for 416x416, 8400 for 640x640):

    * several outputs, one of them ``[..., K, 4]`` (boxes) -> ``nms``;
    * one output ``[K, 6|7]`` -> ``nms``;
    * one output ``[1, a, b]``: ``b == G`` -> ``yolov8``; ``a == 3G`` -> ``yolov5`` (3 anchors
      per point); ``a == G`` -> ``AMBIGUOUS`` (YOLOX raw grid or a decoded anchor-free head);
      ``b`` 6 or 7 with ``a`` not G or 3G -> ``nms`` (``[1, K, 6|7]`` detections);
      otherwise the longer axis holds the candidates: ``a > b`` -> ``yolov5``, ``a < b`` ->
      ``yolov8``; with one dynamic axis, that axis holds the candidates.
    """
    del names  # part of the signature for layouts told apart by name
    if len(shapes) > 1:
        if any(len(s) in (2, 3) and _dim(s[-1]) == 4 for s in shapes):
            return 'nms'
        return None
    if len(shapes) != 1:
        return None
    shape = tuple(shapes[0])
    if len(shape) == 2:
        return 'nms' if _dim(shape[1]) in (6, 7) else None
    if len(shape) != 3:
        return None
    a, b = _dim(shape[1]), _dim(shape[2])
    g = grid_points(size)
    if b is not None and b == g:
        return 'yolov8'
    if a is not None and a == 3 * g and b is not None and b >= 6:
        return 'yolov5'
    if a is not None and a == g and b is not None and b >= 6:
        return AMBIGUOUS
    if b in (6, 7):
        return 'nms'
    if a is not None and b is not None:
        if a > b and b >= 6:
            return 'yolov5'
        if a < b and a >= 5:
            return 'yolov8'
        return None
    if a is None and b is not None and b >= 6:
        return 'yolov5'
    if b is None and a is not None and a >= 5:
        return 'yolov8'
    return None


def looks_raw_grid(rows: npt.NDArray[np.floating[Any]], size: tuple[int, int]) -> bool:
    """Whether ``[N, 5+C]`` rows hold raw YOLOX grid offsets rather than decoded boxes.

    Raw rows have log-sizes (some negative) and centre offsets of a few cells; decoded rows
    have positive sizes and centres spread over the image. Raw when any w/h is negative or the
    centre x values span less than a quarter of the input width.
    """
    import numpy as np

    if rows.shape[0] == 0:
        return False
    if bool((rows[:, 2:4] < 0).any()):
        return True
    spread = float(np.ptp(rows[:, 0]))
    return spread < size[0] / 4


_SCALE_RE = re.compile(r'\s*([0-9.eE+-]+)\s*(?:/\s*([0-9.eE+-]+)\s*)?\Z')
_ALIGN = {
    'topleft': 'topleft',
    'top-left': 'topleft',
    'top_left': 'topleft',
    'tl': 'topleft',
    'center': 'center',
    'centre': 'center',
    'centered': 'center',
    'centred': 'center',
}
_TRUE = {'1', 'true', 'yes', 'on'}
_FALSE = {'0', 'false', 'no', 'off'}


def _parse_scale(where: str, text: str) -> float:
    match = _SCALE_RE.match(text)
    value: float | None = None
    if match:
        try:
            value = float(match[1]) / (float(match[2]) if match[2] else 1.0)
        except (ValueError, ZeroDivisionError):
            value = None
    if value is None or not math.isfinite(value) or value <= 0:
        msg = f'{where}: scale must be a positive number such as 1, 0.00392 or 1/255, got {text!r}'
        raise BackendError(msg)
    return value


def _parse_triple(where: str, key: str, text: str) -> tuple[float, float, float]:
    parts = [p for p in re.split(r'[\s,\[\]()]+', text) if p]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) == 1:
        values *= 3
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        msg = f'{where}: {key} must be one or three numbers, got {text!r}'
        raise BackendError(msg)
    if key == 'std' and any(v == 0 for v in values):
        msg = f'{where}: std must not be 0, got {text!r}'
        raise BackendError(msg)
    return (values[0], values[1], values[2])


_OVERRIDE_KEYS = (
    'channel_order',
    'scale',
    'pad_value',
    'letterbox_align',
    'letterbox',
    'mean',
    'std',
)
#: ``BackendOptions.extra`` keys that every ONNX detector backend passes to the model spec:
#: the preprocessing overrides and ``size`` (the input size of a dynamic-shape model).
SPEC_KEYS = (*_OVERRIDE_KEYS, 'size')


def preprocess_overrides(pre: Preprocess, values: Mapping[str, str], where: str) -> Preprocess:
    """``pre`` with the given keys applied (``channel_order``, ``scale``, ``pad_value``,
    ``letterbox_align``, ``letterbox``, ``mean``, ``std``; values are strings)."""
    changes: dict[str, Any] = {}
    for key, raw in values.items():
        text = raw.strip()
        low = text.lower()
        if key == 'channel_order':
            if low not in ('bgr', 'rgb'):
                msg = f'{where}: channel_order must be bgr or rgb, got {raw!r}'
                raise BackendError(msg)
            changes['channel_order'] = low
        elif key == 'scale':
            changes['scale'] = _parse_scale(where, text)
        elif key == 'pad_value':
            try:
                pad = int(float(text))
            except ValueError:
                pad = -1
            if not 0 <= pad <= 255:
                msg = f'{where}: pad_value must be an integer 0..255, got {raw!r}'
                raise BackendError(msg)
            changes['pad_value'] = pad
        elif key == 'letterbox_align':
            if low not in _ALIGN:
                msg = f'{where}: letterbox_align must be topleft or center, got {raw!r}'
                raise BackendError(msg)
            changes['align'] = _ALIGN[low]
        elif key == 'letterbox':
            if low not in _TRUE | _FALSE:
                msg = f'{where}: letterbox must be true or false, got {raw!r}'
                raise BackendError(msg)
            changes['letterbox'] = low in _TRUE
        elif key in ('mean', 'std'):
            changes[key] = _parse_triple(where, key, text)
    return replace(pre, **changes)


_SIZE_RE = re.compile(r'\d+')


def _size_from_text(text: str) -> tuple[int, int] | None:
    numbers = [int(n) for n in _SIZE_RE.findall(text)]
    if len(numbers) == 1 and numbers[0] > 0:
        return (numbers[0], numbers[0])
    if len(numbers) == 2 and min(numbers) > 0:
        return (numbers[1], numbers[0])  # Ultralytics writes imgsz as [h, w]
    return None


def _parse_size_option(text: str) -> tuple[int, int]:
    match = re.fullmatch(r'\s*(\d+)\s*(?:[xX]\s*(\d+)\s*)?', text)
    if match is None or int(match[1]) <= 0 or (match[2] is not None and int(match[2]) <= 0):
        msg = f'option size must be W or WxH in pixels, got {text!r}'
        raise BackendError(msg)
    width = int(match[1])
    return (width, int(match[2]) if match[2] is not None else width)


def _precision(onnx_type: str, where: str) -> str:
    if onnx_type == 'tensor(float)':
        return 'fp32'
    if onnx_type == 'tensor(float16)':
        return 'fp16'
    msg = f'{where}: input type {onnx_type} is not supported (float32 or float16 inputs only)'
    raise BackendError(msg)


def _open_session(path: Path) -> Any:
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), options, providers=['CPUExecutionProvider'])
    except Exception as exc:  # onnxruntime raises several types for bad files
        msg = f'{path}: cannot load the ONNX model: {type(exc).__name__}: {exc}'
        raise BackendError(msg) from exc


def _shape(value: Sequence[Any]) -> tuple[int | str | None, ...]:
    return tuple(d if isinstance(d, int | str) else None for d in value)


def _fmt_shape(shape: Sequence[int | str | None]) -> str:
    return '[' + ', '.join('?' if d is None else str(d) for d in shape) + ']'


def _primary_output(shapes: Sequence[Sequence[int | str | None]]) -> int:
    for i, shape in enumerate(shapes):
        if len(shape) == 3:
            return i
    return 0


def _probe_rows(session: Any, input_name: str, dtype: str, pre: Preprocess, index: int) -> Any:
    import numpy as np

    w, h = pre.size
    value = (pre.pad_value * pre.scale - pre.mean[0]) / pre.std[0]
    tensor = np.full((1, 3, h, w), value, dtype=np.float16 if dtype == 'fp16' else np.float32)
    name = session.get_outputs()[index].name
    try:
        out = session.run([name], {input_name: tensor})[0]
    except Exception as exc:  # any runtime failure
        msg = f'probe inference failed: {type(exc).__name__}: {exc}'
        raise BackendError(msg) from exc
    return np.asarray(out, dtype=np.float32).reshape(-1, out.shape[-1])


def load_model_spec(
    path: str | Path,
    *,
    family: str | None = None,
    labels: str | None = None,
    session: Any = None,
    overrides: Mapping[str, str] | None = None,
) -> ModelSpec:
    """Read an ONNX detection model's spec; ``BackendError`` with a clear message when unusable.

    ``session``: an onnxruntime ``InferenceSession`` of ``path`` already open (else one is
    made). ``labels``: ``'coco'``, a labels file, or None (metadata ``names``, then defaults).
    ``overrides``: preprocessing keys (see ``preprocess_overrides``) and ``size`` (``W`` or
    ``WxH``, for dynamic inputs), applied after the model's metadata.
    """
    path = Path(path)
    if not path.is_file():
        msg = f'{path}: model file not found'
        raise BackendError(msg)
    if family is not None and family not in FAMILIES:
        msg = f'unknown model family {family!r}; known: {", ".join(FAMILIES)}'
        raise BackendError(msg)
    if session is None:
        session = _open_session(path)
    overrides = dict(overrides or {})
    where = str(path)
    inputs = session.get_inputs()
    if len(inputs) != 1:
        names = ', '.join(f'{i.name} {_fmt_shape(_shape(i.shape))}' for i in inputs)
        msg = f'{where}: expected one image input, the model has {len(inputs)}: {names}'
        raise BackendError(msg)
    inp = inputs[0]
    input_shape = _shape(inp.shape)
    precision = _precision(inp.type, where)
    if len(input_shape) != 4 or _dim(input_shape[1]) not in (None, 3):
        msg = (
            f'{where}: input {inp.name!r} has shape {_fmt_shape(input_shape)}; '
            'expected an NCHW image [1, 3, H, W]'
        )
        raise BackendError(msg)
    if _dim(input_shape[0]) not in (None, 1):
        msg = f'{where}: input batch is fixed at {input_shape[0]}; batch 1 is supported'
        raise BackendError(msg)
    meta = dict(session.get_modelmeta().custom_metadata_map)
    h, w = _dim(input_shape[2]), _dim(input_shape[3])
    size: tuple[int, int] | None = (w, h) if w is not None and h is not None else None
    if 'size' in overrides:
        size = _parse_size_option(overrides['size'])
        if w is not None and h is not None and size != (w, h):
            msg = f'{where}: option size {size[0]}x{size[1]} differs from the fixed input {w}x{h}'
            raise BackendError(msg)
    if size is None and 'imgsz' in meta:
        size = _size_from_text(meta['imgsz'])
    if size is None:
        size = (w or h or DEFAULT_SIZE, h or w or DEFAULT_SIZE)
    outputs = session.get_outputs()
    out_names = [o.name for o in outputs]
    out_shapes = [_shape(o.shape) for o in outputs]

    meta_family = meta.get('replaybench.family', '').strip().lower() or None
    if family is not None:
        source = 'option'
    elif meta_family is not None:
        if meta_family not in FAMILIES:
            msg = (
                f'{where}: metadata replaybench.family={meta_family!r} is not one of '
                f'{", ".join(FAMILIES)}'
            )
            raise BackendError(msg)
        family, source = meta_family, 'metadata'
    else:
        found = family_from_shapes(out_shapes, out_names, size)
        if found is None:
            shown = ', '.join(
                f'{n} {_fmt_shape(s)}' for n, s in zip(out_names, out_shapes, strict=True)
            )
            msg = (
                f'{where}: cannot tell the output layout from outputs {shown}; '
                f'pass --model-family ({", ".join(FAMILIES)})'
            )
            raise BackendError(msg)
        if found == AMBIGUOUS:
            pre = preprocess_overrides(default_preprocess('yolox', size), _meta_pre(meta), where)
            rows = _probe_rows(session, inp.name, precision, pre, _primary_output(out_shapes))
            raw = looks_raw_grid(rows, size)
            family = 'yolox' if raw else 'yolov5'
            source = f'output shape + probe ({"raw grid" if raw else "decoded boxes"})'
        else:
            family, source = found, 'output shapes'

    pre = default_preprocess(family, size)
    pre = preprocess_overrides(pre, _meta_pre(meta), f'{where} metadata')
    pre_keys = {k: v for k, v in overrides.items() if k in _OVERRIDE_KEYS}
    pre = preprocess_overrides(pre, pre_keys, 'backend options')

    if family == 'nms':
        run_names = tuple(out_names)
        num_classes = None
    else:
        primary = _primary_output(out_shapes)
        shape = out_shapes[primary]
        if len(shape) != 3:
            msg = (
                f'{where}: family {family} needs a [1, ., .] output, '
                f'got {out_names[primary]} {_fmt_shape(shape)}'
            )
            raise BackendError(msg)
        run_names = (out_names[primary],)
        channels = _dim(shape[1]) if family == 'yolov8' else _dim(shape[2])
        extra = 4 if family == 'yolov8' else 5
        if channels is not None and channels <= extra:
            msg = (
                f'{where}: output {out_names[primary]} {_fmt_shape(shape)} has no class scores '
                f'for family {family}'
            )
            raise BackendError(msg)
        num_classes = channels - extra if channels is not None else None
        rows = _dim(shape[1])
        if family == 'yolox' and rows is not None and rows != grid_points(size):
            msg = (
                f'{where}: yolox: output {out_names[primary]} has {rows} rows; a '
                f'{size[0]}x{size[1]} input with strides {", ".join(map(str, STRIDES))} '
                f'gives {grid_points(size)}'
            )
            raise BackendError(msg)
    try:
        class_names, labels_source = resolve_labels(labels, meta.get('names'), num_classes)
    except BackendError as exc:
        msg = f'{where}: {exc}'
        raise BackendError(msg) from exc
    return ModelSpec(
        path=path,
        sha256=file_sha256(path),
        input_name=inp.name,
        output_names=run_names,
        family=family,
        preprocess=pre,
        class_names=class_names,
        precision=precision,
        family_source=source,
        labels_source=labels_source,
        input_shape=input_shape,
        output_shapes=tuple(out_shapes),
        metadata=meta,
    )


def _meta_pre(meta: Mapping[str, str]) -> dict[str, str]:
    """Preprocessing keys from ``replaybench.*`` metadata."""
    out: dict[str, str] = {}
    for key in _OVERRIDE_KEYS:
        value = meta.get(f'replaybench.{key}')
        if value is not None and value.strip():
            out[key] = value
    return out
