"""Segmentation model outputs -> a label mask in source pixels.

A segmentation model answers in one of two ways, each in two or three tensor layouts:

* class scores (logits or probabilities): ``[1, C, H, W]`` (``logits-nchw``) or
  ``[1, H, W, C]`` (``logits-nhwc``); the label of a pixel is the argmax over C (the first
  class wins a tie, as ``numpy.argmax`` does);
* class ids: ``[1, H, W]``, ``[1, 1, H, W]`` or ``[1, H, W, 1]`` (``labels``), as TAO U-Net's
  ``argmax_1`` output or a model with the argmax in its graph gives them.

``layout_from_shape`` tells which from the output's shape, dtype and the model's input size;
the model's ``replaybench.seg_layout`` metadata or an explicit layout (``--model-family``)
overrides it. ``SourceMapper`` maps the model-sized label map back onto the frame by nearest
neighbour: source pixel ``(x, y)`` takes the label under its centre, carried through the same
letterbox or stretch ``Transform`` that made the input, then scaled to the output's grid when
the model's output is smaller than its input (a stride)::

    x_in  = (x + 0.5) * scale_x + pad_x           (model-input pixels)
    x_out = clip(floor(x_in * W_out / W_in), 0, W_out - 1)

and the same for ``y``; pixels that fall in the padding cannot occur (the letterbox puts the
whole frame inside the input).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Literal, NamedTuple, cast

import numpy as np

from replaybench.errors import BackendError

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from replaybench.detector.preprocess import Transform

__all__ = [
    'LAYOUTS',
    'Layout',
    'SegLayout',
    'SourceMapper',
    'decode_labels',
    'layout_from_shape',
    'parse_layout',
    'source_indices',
]

Layout = Literal['logits-nchw', 'logits-nhwc', 'labels']
#: The output layouts the decoder reads (the values of ``--model-family`` for segmentation).
LAYOUTS: tuple[Layout, ...] = ('logits-nchw', 'logits-nhwc', 'labels')

_INTEGER_TYPES = ('int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64')


class SegLayout(NamedTuple):
    """An output's layout and what it says: ``num_classes`` (None for ``labels``), and the
    output's spatial size ``(width, height)`` (None where the shape is dynamic)."""

    layout: Layout
    num_classes: int | None
    size: tuple[int, int] | None


def parse_layout(text: str, where: str = 'layout') -> Layout:
    """``text`` as one of ``LAYOUTS`` (case and ``_`` / ``-`` ignored); ``BackendError`` else."""
    low = text.strip().lower().replace('_', '-')
    for layout in LAYOUTS:
        if low == layout:
            return layout
    msg = f'{where}: unknown segmentation layout {text!r}; known: {", ".join(LAYOUTS)}'
    raise BackendError(msg)


def _dim(value: object) -> int | None:
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 else None


def _fmt(shape: Sequence[object]) -> str:
    return '[' + ', '.join(str(d) if _dim(d) is not None else '?' for d in shape) + ']'


def _proportional(h: int | None, w: int | None, input_size: tuple[int, int] | None) -> bool:
    """Whether ``h x w`` is the input's size divided by one integer stride."""
    if h is None or w is None or input_size is None:
        return False
    in_w, in_h = input_size
    if in_h % h or in_w % w:
        return False
    return in_h // h == in_w // w


def _with(layout: Layout, shape: Sequence[object]) -> SegLayout:
    dims = [_dim(d) for d in shape]
    if layout == 'logits-nchw':
        h, w = dims[2], dims[3]
        classes = dims[1]
    elif layout == 'logits-nhwc':
        h, w = dims[1], dims[2]
        classes = dims[3]
    elif len(dims) == 3:
        h, w, classes = dims[1], dims[2], None
    elif dims[1] == 1:
        h, w, classes = dims[2], dims[3], None
    else:
        h, w, classes = dims[1], dims[2], None
    size = (w, h) if w is not None and h is not None else None
    return SegLayout(layout, classes, size)


def layout_from_shape(
    shape: Sequence[object],
    dtype: str,
    *,
    input_size: tuple[int, int] | None = None,
    declared: str | None = None,
    where: str = 'output',
) -> tuple[SegLayout, str]:
    """The layout of one output, and how it was found (``option``, ``metadata``, ``shape``).

    ``shape``: the output's shape (ints, None or names for dynamic dimensions); ``dtype``:
    numpy's name of its element type (``float32``, ``int64``, ...); ``input_size``: the
    model's input ``(width, height)``; ``declared``: a layout given by option or metadata
    (``'option:labels'`` / ``'metadata:labels'`` name the source). Rules without a
    declaration: rank 3, or rank 4 with a 1 at axis 1 or 3, or an integer dtype: ``labels``;
    rank 4 with floats: ``logits-nchw`` when axes 2-3 are the input divided by a stride (or
    only axis 1 is small), ``logits-nhwc`` when axes 1-2 are. Otherwise ``BackendError``
    asking for ``--model-family``.
    """
    rank = len(shape)
    if rank not in (3, 4) or _dim(shape[0]) not in (None, 1):
        msg = (
            f'{where} {_fmt(shape)}: a segmentation output is [1, C, H, W], [1, H, W, C], '
            '[1, H, W], [1, 1, H, W] or [1, H, W, 1]'
        )
        raise BackendError(msg)
    if declared is not None:
        source, _, text = declared.partition(':')
        layout = parse_layout(text, f'{where} ({source})')
        d1, d3 = (_dim(shape[1]), _dim(shape[3])) if rank == 4 else (1, 1)
        if layout == 'labels' and 1 not in (d1, d3) and d1 is not None and d3 is not None:
            msg = f'{where} {_fmt(shape)}: labels need a 1 at axis 1 or 3 of a 4-D output'
            raise BackendError(msg)
        if layout != 'labels' and rank != 4:
            msg = f'{where} {_fmt(shape)}: {layout} needs a 4-D output'
            raise BackendError(msg)
        return _with(layout, shape), source
    integer = dtype in _INTEGER_TYPES
    if rank == 3:
        return _with('labels', shape), 'shape'
    d1, d2, d3 = _dim(shape[1]), _dim(shape[2]), _dim(shape[3])
    if d1 == 1 or d3 == 1:
        return _with('labels', shape), 'shape'
    if integer:
        msg = f'{where} {_fmt(shape)}: integer class ids need a 1 at axis 1 or 3 of a 4-D output'
        raise BackendError(msg)
    nchw = _proportional(d2, d3, input_size)
    nhwc = _proportional(d1, d2, input_size)
    if nchw != nhwc:
        return _with('logits-nchw' if nchw else 'logits-nhwc', shape), 'shape'
    if d1 is not None and d3 is not None and d1 != d3:
        return _with('logits-nchw' if d1 < d3 else 'logits-nhwc', shape), 'shape'
    msg = (
        f'{where} {_fmt(shape)}: cannot tell class scores [1, C, H, W] from [1, H, W, C]; '
        f'pass --model-family ({", ".join(LAYOUTS)})'
    )
    raise BackendError(msg)


def decode_labels(output: npt.NDArray[Any], layout: Layout) -> npt.NDArray[np.uint8]:
    """The model-sized ``H x W`` uint8 label map of one output.

    Scores: argmax over the class axis (NaN counts as the largest, as in ``numpy.argmax``);
    more than 256 classes is a ``BackendError``. Labels: the ids as they are; an id outside
    0..255 is a ``BackendError`` (a mask holds uint8 class ids).
    """
    if layout == 'labels':
        if output.ndim == 4:
            plane = output[0, 0] if output.shape[1] == 1 else output[0, :, :, 0]
        elif output.ndim == 3:
            plane = output[0]
        else:
            msg = f'labels output has shape {list(output.shape)}; expected 3 or 4 axes'
            raise BackendError(msg)
        if plane.dtype == np.uint8:
            return np.ascontiguousarray(plane)
        if plane.dtype.kind == 'f' and (
            not np.isfinite(plane).all() or not np.array_equal(plane, np.round(plane))
        ):
            msg = 'labels output holds values that are not whole class ids'
            raise BackendError(msg)
        low, high = (plane.min(), plane.max()) if plane.size else (0, 0)
        if low < 0 or high > 255:
            msg = f'labels output holds class id {low if low < 0 else high}; ids must be 0..255'
            raise BackendError(msg)
        return plane.astype(np.uint8)
    if output.ndim != 4:
        msg = f'{layout} output has shape {list(output.shape)}; expected 4 axes'
        raise BackendError(msg)
    axis = 0 if layout == 'logits-nchw' else 2
    classes = output.shape[1 if layout == 'logits-nchw' else 3]
    if classes > 256:
        msg = f'{layout} output has {classes} classes; a uint8 mask holds at most 256'
        raise BackendError(msg)
    if layout == 'logits-nchw' and output.dtype == np.float32 and 1 < classes <= 32:
        fast = _argmax_planes(output[0])
        if fast is not None:
            return fast
    return cast('npt.NDArray[np.uint8]', np.argmax(output[0], axis=axis).astype(np.uint8))


def _argmax_planes(planes: npt.NDArray[np.float32]) -> npt.NDArray[np.uint8] | None:
    """``argmax`` over axis 0 of ``[C, H, W]`` float32 scores, one class plane at a time with
    OpenCV (a running maximum and the index where a plane beats it: the first class wins a
    tie); None when a score is NaN or infinite (``numpy.argmax`` decides those)."""
    import cv2

    finite, _ = cv2.checkRange(planes.reshape(planes.shape[0], -1))
    if not finite:  # a NaN or an infinity
        return None
    best = np.array(planes[0], dtype=np.float32, order='C')
    labels = np.zeros(best.shape, dtype=np.uint8)
    ids = np.zeros(best.shape, dtype=np.uint8)
    beats = np.empty(best.shape, dtype=np.uint8)
    for c in range(1, planes.shape[0]):
        plane = np.ascontiguousarray(planes[c])
        cv2.compare(plane, best, cv2.CMP_GT, dst=beats)
        cv2.max(best, plane, dst=best)
        cv2.add(ids, c, dst=labels, mask=beats)  # type: ignore[call-overload, unused-ignore]
    return labels


def source_indices(
    transform: Transform, input_size: tuple[int, int], output_size: tuple[int, int]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp]]:
    """For every source column and row, the output column and row under its centre.

    ``input_size`` / ``output_size``: ``(width, height)`` of the model's input and output.
    """
    in_w, in_h = input_size
    out_w, out_h = output_size
    sx = transform.scale
    sy = transform.scale if transform.scale_y is None else transform.scale_y
    xs = (np.arange(transform.src_w, dtype=np.float64) + 0.5) * sx + transform.pad_x
    ys = (np.arange(transform.src_h, dtype=np.float64) + 0.5) * sy + transform.pad_y
    cols = np.clip(np.floor(xs * (out_w / in_w)).astype(np.intp), 0, out_w - 1)
    rows = np.clip(np.floor(ys * (out_h / in_h)).astype(np.intp), 0, out_h - 1)
    return cols, rows


def _resize_matches(
    cols: npt.NDArray[np.intp],
    rows: npt.NDArray[np.intp],
    out_size: tuple[int, int],
    transform: Transform,
) -> bool:
    """Whether ``cv2.resize`` with ``INTER_NEAREST_EXACT`` picks exactly ``cols`` and ``rows``
    (a stretched input usually: it samples pixel centres too), checked on index ramps."""
    import cv2

    out_w, out_h = out_size
    if max(out_w, out_h) > 65535:
        return False
    ramp_x = np.arange(out_w, dtype=np.uint16).reshape(1, out_w)
    ramp_y = np.arange(out_h, dtype=np.uint16).reshape(out_h, 1)
    got_x = cv2.resize(ramp_x, (transform.src_w, 1), interpolation=cv2.INTER_NEAREST_EXACT)
    got_y = cv2.resize(ramp_y, (1, transform.src_h), interpolation=cv2.INTER_NEAREST_EXACT)
    return bool(np.array_equal(got_x.reshape(-1), cols) and np.array_equal(got_y.reshape(-1), rows))


class SourceMapper:
    """Nearest-neighbour map of model-sized label maps onto the frame, reused across frames.

    The source indices are worked out once per (transform, output size); each call returns a
    fresh frame-sized uint8 array: ``cv2.resize`` (``INTER_NEAREST_EXACT``) where it was checked
    to pick the same pixels (a stretched input), else ``cv2.remap`` with integer maps (an exact
    table lookup).
    """

    def __init__(self, input_size: tuple[int, int]) -> None:
        self.input_size = input_size
        self._key: tuple[Transform, tuple[int, int]] | None = None
        self._map: npt.NDArray[np.int16] | None = None
        self._cols: npt.NDArray[np.intp] | None = None
        self._rows: npt.NDArray[np.intp] | None = None
        self._resize = False

    def __call__(
        self, labels: npt.NDArray[np.uint8], transform: Transform
    ) -> npt.NDArray[np.uint8]:
        import cv2

        out_size = (int(labels.shape[1]), int(labels.shape[0]))
        key = (transform, out_size)
        if self._key != key:
            cols, rows = source_indices(transform, self.input_size, out_size)
            self._cols, self._rows = cols, rows
            self._resize = _resize_matches(cols, rows, out_size, transform)
            if max(out_size) < 32768 and max(transform.src_w, transform.src_h) < 32768:
                grid = np.empty((transform.src_h, transform.src_w, 2), dtype=np.int16)
                grid[:, :, 0] = cols[None, :]
                grid[:, :, 1] = rows[:, None]
                self._map = grid
            else:
                self._map = None
            self._key = key
        if self._resize:
            size = (transform.src_w, transform.src_h)
            resized = cv2.resize(labels, size, interpolation=cv2.INTER_NEAREST_EXACT)
            return cast('npt.NDArray[np.uint8]', resized)
        if self._map is not None:
            mapped = cv2.remap(labels, self._map, None, cv2.INTER_NEAREST)  # type: ignore[call-overload, unused-ignore]
            return cast('npt.NDArray[np.uint8]', mapped)
        assert self._rows is not None
        assert self._cols is not None
        return np.ascontiguousarray(labels[self._rows[:, None], self._cols[None, :]])
