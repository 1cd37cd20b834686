"""Frame -> model input tensor (letterbox or stretch, channel order, scale, mean/std).

Per frame: one ``cv2.resize`` straight into a preallocated padded canvas (the pad is written
once per source size), then one strided copy into the preallocated NCHW float32 tensor that
also casts and reorders channels, and one in-place multiply when ``scale`` / ``mean`` / ``std``
call for it. ``Transform`` maps boxes in model-input pixels back to source pixels.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.errors import BackendError

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.detector.spec import Preprocess

__all__ = [
    'Letterboxer',
    'Transform',
    'boxes_to_source',
    'geometry',
    'letterbox',
]

#: Channel layout of the encodings the letterboxer reads directly; others go through to_bgr8.
_LAYOUTS = {'bgr8': 'bgr', 'rgb8': 'rgb', 'bgra8': 'bgra', 'rgba8': 'rgba', 'mono8': 'y'}


class Transform(NamedTuple):
    """Model-input pixels -> source pixels: ``x_src = (x - pad_x) / scale``, clipped.

    ``scale_y`` is the vertical scale when it differs from ``scale`` (stretched, not
    letterboxed, input); None means ``scale`` for both axes.
    """

    scale: float
    pad_x: float
    pad_y: float
    src_w: int
    src_h: int
    scale_y: float | None = None


def geometry(src_w: int, src_h: int, pre: Preprocess) -> tuple[int, int, int, int, Transform]:
    """``(new_w, new_h, left, top, transform)``: where the resized frame sits in the input."""
    width, height = pre.size
    if src_w <= 0 or src_h <= 0:
        msg = f'cannot preprocess an empty {src_w}x{src_h} image'
        raise BackendError(msg)
    if not pre.letterbox:
        transform = Transform(width / src_w, 0.0, 0.0, src_w, src_h, height / src_h)
        return width, height, 0, 0, transform
    r = min(width / src_w, height / src_h)
    new_w = min(max(round(src_w * r), 1), width)
    new_h = min(max(round(src_h * r), 1), height)
    if pre.align == 'center':
        left, top = (width - new_w) // 2, (height - new_h) // 2
    else:
        left, top = 0, 0
    return new_w, new_h, left, top, Transform(r, float(left), float(top), src_w, src_h)


def boxes_to_source(
    boxes: npt.NDArray[np.floating[Any]], transform: Transform
) -> npt.NDArray[np.float32]:
    """``[N, 4]`` x0, y0, x1, y1 in model-input pixels -> source pixels, clipped to the image."""
    out = np.empty((boxes.shape[0], 4), dtype=np.float32)
    sy = transform.scale if transform.scale_y is None else transform.scale_y
    np.subtract(boxes[:, 0::2], transform.pad_x, out=out[:, 0::2], casting='unsafe')
    np.subtract(boxes[:, 1::2], transform.pad_y, out=out[:, 1::2], casting='unsafe')
    out[:, 0::2] /= np.float32(transform.scale)
    out[:, 1::2] /= np.float32(sy)
    np.clip(out[:, 0::2], 0, transform.src_w, out=out[:, 0::2])
    np.clip(out[:, 1::2], 0, transform.src_h, out=out[:, 1::2])
    return out


class _Canvas(NamedTuple):
    key: tuple[int, int, int]
    canvas: npt.NDArray[np.uint8]
    roi: npt.NDArray[np.uint8]
    new_w: int
    new_h: int
    transform: Transform


class Letterboxer:
    """Reusable preprocessor for one ``Preprocess``; returns the same tensor object each call.

    The tensor is ``[1, 3, H, W]`` float32 (float16 when ``precision='fp16'``), C-contiguous,
    overwritten by the next call. Encodings other than bgr8 / rgb8 / bgra8 / rgba8 / mono8
    are converted with ``decode.to_bgr8`` first (mono16 and 32FC1 scaled by the frame's max).
    """

    def __init__(self, pre: Preprocess, precision: str = 'fp32') -> None:
        import cv2

        self._cv2 = cv2
        self.pre = pre
        width, height = pre.size
        self.tensor: npt.NDArray[np.float32] = np.empty((1, 3, height, width), dtype=np.float32)
        self.output: npt.NDArray[Any] = self.tensor
        if precision == 'fp16':
            self.output = np.empty((1, 3, height, width), dtype=np.float16)
        elif precision != 'fp32':
            msg = f'unsupported input precision {precision!r} (fp32 or fp16)'
            raise BackendError(msg)
        gains = [pre.scale / s for s in pre.std]
        offsets = [-m / s for m, s in zip(pre.mean, pre.std, strict=True)]
        self._gains = np.asarray(gains, dtype=np.float32)
        self._offsets = np.asarray(offsets, dtype=np.float32)
        self._uniform = len(set(gains)) == 1 and not any(offsets)
        self._identity = self._uniform and gains[0] == 1.0
        self._gain = np.float32(gains[0])
        self._state: _Canvas | None = None

    def _canvas(self, height: int, width: int, channels: int) -> _Canvas:
        key = (height, width, channels)
        state = self._state
        if state is not None and state.key == key:
            return state
        new_w, new_h, left, top, transform = geometry(width, height, self.pre)
        out_w, out_h = self.pre.size
        shape = (out_h, out_w) if channels == 1 else (out_h, out_w, channels)
        canvas = np.full(shape, self.pre.pad_value, dtype=np.uint8)
        roi = canvas[top : top + new_h, left : left + new_w]
        state = _Canvas(key, canvas, roi, new_w, new_h, transform)
        self._state = state
        return state

    def __call__(
        self, image: npt.NDArray[Any], encoding: str
    ) -> tuple[npt.NDArray[Any], Transform]:
        layout = _LAYOUTS.get(encoding)
        if layout is None:
            from replaybench.decode import to_bgr8

            image, layout = to_bgr8(image, encoding), 'bgr'
        if image.ndim == 3 and image.shape[2] == 1:
            image = image[:, :, 0]
        channels = 1 if image.ndim == 2 else int(image.shape[2])
        if image.dtype != np.uint8 or channels != len(layout) or image.ndim not in (2, 3):
            msg = (
                f'expected a {len(layout)}-channel uint8 image for {encoding}, '
                f'got shape {image.shape} {image.dtype}'
            )
            raise BackendError(msg)
        state = self._canvas(int(image.shape[0]), int(image.shape[1]), channels)
        cv2 = self._cv2
        resized = cv2.resize(
            image, (state.new_w, state.new_h), dst=state.roi, interpolation=cv2.INTER_LINEAR
        )
        if resized is not state.roi:  # OpenCV allocated instead of writing in place
            state.roi[...] = resized
        tensor = self.tensor
        canvas = state.canvas
        if channels == 1:
            np.copyto(tensor[0], canvas[None], casting='unsafe')
        else:
            planes = canvas.transpose(2, 0, 1)
            same = layout[:3] == self.pre.channel_order
            np.copyto(tensor[0], planes[0:3] if same else planes[2::-1], casting='unsafe')
        if not self._identity:
            if self._uniform:
                np.multiply(tensor, self._gain, out=tensor)
            else:
                for c in range(3):
                    plane = tensor[0, c]
                    np.multiply(plane, self._gains[c], out=plane)
                    np.add(plane, self._offsets[c], out=plane)
        if self.output is not tensor:
            np.copyto(self.output, tensor, casting='unsafe')
        return self.output, state.transform


def letterbox(
    image: npt.NDArray[Any], encoding: str, pre: Preprocess
) -> tuple[npt.NDArray[Any], Transform]:
    """One-off ``Letterboxer(pre)(image, encoding)`` with a fresh tensor."""
    return Letterboxer(pre)(image, encoding)
