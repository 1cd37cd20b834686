"""A model's input on one torch device: the frame's pixels uploaded once (through a reused
pinned buffer on CUDA), then letterboxed or stretched, normalised and written into the input
tensor the engines bind (``DeviceInput``); the base of the detection and segmentation pipelines
of ``cuda`` / ``tensorrt``. ``frame_input`` gives a frame's pixels as uploaded."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.backends.gpu import _torch_ops as ops
from replaybench.errors import BackendError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    import numpy.typing as npt

    from replaybench.detector.preprocess import Transform
    from replaybench.detector.spec import Preprocess
    from replaybench.types import Frame

__all__ = ['DeviceInput', 'frame_input']

#: Encodings uploaded as they are, with their channel layout; others go through to_bgr8.
_LAYOUTS = {'bgr8': 'bgr', 'rgb8': 'rgb', 'bgra8': 'bgra', 'rgba8': 'rgba', 'mono8': 'y'}
Tensor = Any  # torch.Tensor


def frame_input(frame: Frame, backend: str) -> tuple[npt.NDArray[np.uint8], str]:
    """The frame's uint8 pixels as uploaded and their channel layout; depth is refused."""
    if frame.is_depth or frame.encoding == '32FC1':
        msg = (
            f'{backend}: frame {frame.topic}#{frame.seq} is a depth image '
            f'({frame.source_encoding}); a detector for colour images cannot use it: '
            'replay colour or mono topics only'
        )
        raise BackendError(msg)
    image = frame.image
    layout = _LAYOUTS.get(frame.encoding)
    if layout is None:
        from replaybench.decode import to_bgr8

        image, layout = to_bgr8(image, frame.encoding), 'bgr'
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    channels = 1 if image.ndim == 2 else int(image.shape[2])
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or channels != len(layout):
        msg = (
            f'{backend}: frame {frame.topic}#{frame.seq}: expected a {len(layout)}-channel '
            f'uint8 image for {frame.encoding}, got shape {image.shape} {image.dtype}'
        )
        raise BackendError(msg)
    return np.asarray(image, dtype=np.uint8), layout


class DeviceInput:
    """Upload and preprocessing for one model on one torch device.

    ``input`` is the model's input tensor ``[1, 3, H, W]`` that engines bind; the device may be
    the CPU for tests (no pinned memory there).
    """

    def __init__(self, torch: Any, pre: Preprocess, device: Any, half: bool) -> None:
        self.torch = torch
        self.device = device
        self.pre = pre
        width, height = pre.size
        dtype = torch.float16 if half else torch.float32
        self.input = torch.empty((1, 3, height, width), dtype=dtype, device=device)
        self._work = self.input if not half else torch.empty_like(self.input, dtype=torch.float32)
        self._norm = ops.normaliser(torch, pre, device)
        self._pinned: Tensor = None

    def upload(self, pixels: npt.NDArray[np.uint8]) -> Tensor:
        """The pixels on the device; through one reused pinned buffer on CUDA."""
        return self.transfer(self.stage(pixels))

    def stage(self, pixels: npt.NDArray[np.uint8]) -> Tensor:
        """The host side of the upload: the pixels copied into the reused pinned buffer (CUDA),
        or a CPU tensor of their own; no GPU call."""
        torch = self.torch
        if self.device.type != 'cuda':
            return torch.from_numpy(np.array(pixels))
        pinned = self._pinned
        if pinned is None or tuple(pinned.shape) != pixels.shape:
            pinned = self._pinned = torch.empty(pixels.shape, dtype=torch.uint8, pin_memory=True)
        np.copyto(pinned.numpy(), pixels)
        return pinned

    def transfer(self, host: Tensor) -> Tensor:
        """The staged pixels copied to the device, queued on the current stream."""
        if self.device.type != 'cuda':
            return host
        return host.to(self.device, non_blocking=True)

    def preprocess(
        self, image: Tensor, layout: str, begin: Callable[[], object] | None = None
    ) -> Transform:
        """Write the model input for ``image`` (on the device) into ``input``; ``begin`` is
        called just before the first GPU call (after the letterbox geometry on the host)."""
        from replaybench.detector.preprocess import geometry

        height, width = int(image.shape[0]), int(image.shape[1])
        new_w, new_h, left, top, transform = geometry(width, height, self.pre)
        if begin is not None:
            begin()
        ops.letterbox_into(
            self.torch, self._work, image, layout, self.pre, (new_w, new_h, left, top), self._norm
        )
        if self._work is not self.input:
            self.input.copy_(self._work)
        return transform

    def download(self, tensors: Sequence[Tensor]) -> list[npt.NDArray[Any]]:
        """The tensors copied to the host as numpy arrays."""
        return [t.detach().to('cpu').numpy() for t in tensors]
