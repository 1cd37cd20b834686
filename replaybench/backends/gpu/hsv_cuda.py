"""The hsv colour-blob detector on an NVIDIA GPU with CuPy.

Same configuration, classes, thresholds and score as ``hsv`` (``--config``, ``options.extra``).
Per frame: upload once from pinned host memory (h2d), RGB->HSV (preprocess), class masks with
open/close (infer), one connected-component labelling of all class masks and per-blob
statistics (postprocess, on the GPU), download of the blob table only (d2h), then boxes and
scores on the host (postprocess). See ``_hsv_ops`` for how it differs from OpenCV's contours.
"""

from __future__ import annotations

import importlib
import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from replaybench.backends.base import Availability, BackendOptions
from replaybench.backends.gpu import _hsv_ops
from replaybench.backends.gpu._cuda import (
    STAGE_EVENTS,
    EventTimer,
    StageClock,
    device_facts,
    driver_problem,
)
from replaybench.backends.gpu.availability import hsv_cuda_availability
from replaybench.backends.hsv import HsvBackend, blob_score
from replaybench.decode import to_bgr8
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.types import BackendResult, Detection, StageTimes

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.backends.hsv import ColorClass, HsvConfig
    from replaybench.types import Frame

__all__ = [
    'HsvCudaBackend',
    'detections_from_stats',
    'frame_pixels',
    'morphology_kernel',
    'warmup_image',
]

#: Encodings uploaded as they are, and the channel index of blue in each.
_BLUE = {'bgr8': 0, 'bgra8': 0, 'rgb8': 2, 'rgba8': 2}


def morphology_kernel(config: HsvConfig) -> npt.NDArray[np.bool_] | None:
    """The elliptic structuring element of ``config`` (OpenCV's), None when morphology is off."""
    import cv2

    params = config.detector
    if params.kernel <= 1 or params.open_iterations + params.close_iterations == 0:
        return None
    size = (params.kernel, params.kernel)
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, size), dtype=bool)


def frame_pixels(frame: Frame) -> tuple[npt.NDArray[np.uint8], int]:
    """The frame's HxWx3|4 uint8 pixels as uploaded and the channel index of blue.

    bgr8 / rgb8 / bgra8 / rgba8 go up as they are; other encodings are converted on the host.
    """
    image = frame.image
    blue = _BLUE.get(frame.encoding)
    if blue is None:
        image, blue = to_bgr8(image, frame.encoding), 0
    if image.ndim != 3 or image.shape[2] not in (3, 4) or image.dtype != np.uint8:
        msg = (
            f'hsv-cuda: frame {frame.topic}#{frame.seq}: expected HxWx3 uint8 for '
            f'{frame.encoding}, got shape {image.shape} {image.dtype}'
        )
        raise BackendError(msg)
    return np.asarray(image, dtype=np.uint8), blue


def _class_colour(cls: ColorClass) -> tuple[int, int, int]:
    """A BGR colour whose HSV (OpenCV's, as ``to_hsv`` computes it) lies inside ``cls``."""
    import cv2

    tables = _hsv_ops.hsv_tables()
    for lo, hi in cls.ranges:
        mid = [(a + b) // 2 for a, b in zip(lo, hi, strict=True)]
        for h, s, v in ((mid[0], mid[1], mid[2]), (mid[0], hi[1], hi[2]), tuple(lo)):
            hsv = np.array([[[min(h, 179), s, v]]], dtype=np.uint8)
            bgr = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
            back = [int(p[0, 0]) for p in _hsv_ops.to_hsv(np, bgr, 0, tables)]
            if any(
                all(a <= x <= b for a, x, b in zip(l2, back, h2, strict=True))
                for l2, h2 in cls.ranges
            ):
                b, g, r = (int(c) for c in bgr[0, 0])
                return b, g, r
    msg = f'hsv-cuda: no 8-bit colour falls inside class {cls.name!r}'
    raise BackendError(msg)


def warmup_image(config: HsvConfig) -> npt.NDArray[np.uint8]:
    """A BGR image with one square blob per class that survives the morphology and the minimum
    area: a warm-up frame on it runs every kernel, labelling and statistics included.

    A square of side ``s`` keeps its full size through an open with a ``k`` x ``k`` kernel
    (``s >= k``) and the close; ``s`` is also made larger than ``sqrt(min_area)`` plus a
    margin for the contour-area estimate.
    """
    params = config.detector
    reach = max(params.kernel, 1) * (params.open_iterations + params.close_iterations + 1)
    side = max(16, 2 * reach, int(np.ceil(np.sqrt(max(params.min_area, 0.0)))) + 8)
    gap = side + 2 * reach
    classes = config.classes
    image = np.zeros((side + 2 * gap, gap + len(classes) * (side + gap), 3), dtype=np.uint8)
    for index, cls in enumerate(classes):
        x0 = gap + index * (side + gap)
        image[gap : gap + side, x0 : x0 + side] = _class_colour(cls)
    return image


def _sort_key(det: Detection) -> tuple[int, float, float, float, float, float]:
    return (det.class_index, -det.score, det.y0, det.x0, det.y1, det.x1)


def detections_from_stats(
    rows: npt.NDArray[np.float64], config: HsvConfig
) -> tuple[Detection, ...]:
    """Detections from downloaded ``blob_stats`` rows: minimum area, boxes, scores, hsv order."""
    min_area = config.detector.min_area
    found: list[Detection] = []
    for st in _hsv_ops.read_stats(rows):
        if st.pixels == 0 or _hsv_ops.contour_area_estimate(st.filled, st.boundary) < min_area:
            continue
        cls = config.classes[st.class_index]
        width, height = st.x1 - st.x0, st.y1 - st.y0
        score = blob_score(st.pixels, width * height, st.sum_s / st.pixels, cls.saturation_floor)
        found.append(
            Detection(
                st.class_index,
                cls.name,
                score,
                float(st.x0),
                float(st.y0),
                float(st.x1),
                float(st.y1),
            )
        )
    found.sort(key=_sort_key)
    return tuple(found)


class HsvCudaBackend:
    """hsv on the GPU (CuPy); ``options.device`` picks the GPU."""

    name: ClassVar[str] = 'hsv-cuda'
    description: ClassVar[str] = (
        'hsv colour blobs on an NVIDIA GPU (CuPy: HSV, masks, open/close, labelling)'
    )
    #: Runs on the GPU ``options.device`` (``Backend.device``).
    device: ClassVar[str] = 'cuda'

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        # The hsv backend parses --config and the [detector] overrides the same way.
        self.config = HsvBackend(self.options).config
        self._kernel = morphology_kernel(self.config)
        self._cp: Any = None
        self._ndi: Any = None
        self._device: Any = None
        self._stream: Any = None
        self._tables: Any = None  # (sdiv, hdiv) on the device
        self._gpu_kernel: Any = None
        self._pinned: Any = None
        self._events: EventTimer | None = None
        self._facts: dict[str, Any] = {}

    @classmethod
    def available(cls) -> Availability:
        return hsv_cuda_availability()

    def open(self) -> None:
        """Import CuPy, put the tables on the GPU and run one whole frame (the warm-up)."""
        index = self.options.device
        problem = driver_problem(index)
        if problem is not None:
            msg = f'hsv-cuda: {problem}'
            raise BackendUnavailableError(msg)
        try:
            cupy = importlib.import_module('cupy')
            ndimage = importlib.import_module('cupyx.scipy.ndimage')
        except Exception as exc:  # ImportError and CUDA library load failures
            msg = f'hsv-cuda: cannot import cupy: {type(exc).__name__}: {exc}'
            raise BackendUnavailableError(msg) from exc
        self._cp, self._ndi = cupy, ndimage
        self._device = cupy.cuda.Device(index)
        facts = device_facts(index)
        self._facts = {
            'device': index,
            'device_name': facts.name,
            'device_uuid': facts.uuid,
            'device_pci_bus_id': facts.pci_bus_id,
            'compute_capability': facts.compute_capability,
            'driver': facts.driver,
            'cuda_version': _cupy_cuda_version(cupy),
            'device_memory_bytes': facts.total_memory_bytes,
            'cupy': str(cupy.__version__),
        }
        try:
            with self._device:
                stream = self._stream = cupy.cuda.Stream(non_blocking=True)
                sdiv, hdiv = _hsv_ops.hsv_tables()
                # copied on the backend's stream, so the kernels queued after them on it
                # (the non-blocking stream does not wait for the null stream) see them
                with stream:
                    self._tables = (cupy.asarray(sdiv), cupy.asarray(hdiv))
                    kernel = self._kernel
                    self._gpu_kernel = None if kernel is None else cupy.asarray(kernel)
                events = [cupy.cuda.Event() for _ in range(STAGE_EVENTS)]
                self._events = EventTimer(
                    events, lambda e: e.record(stream), cupy.cuda.get_elapsed_time
                )
                self._warm_up()
        except Exception as exc:  # missing CUDA runtime parts (NVRTC, ...)
            self.close()
            msg = f'hsv-cuda: CuPy cannot run its kernels: {type(exc).__name__}: {exc}'
            raise BackendUnavailableError(msg) from exc

    def close(self) -> None:
        """Drop the device buffers and return CuPy's cached blocks (device and pinned), so that
        the next backend's GPU memory figure is its own.

        CuPy's default memory pool frees the blocks of the current device only, so this runs
        with ``options.device`` current (``--device 1`` returns GPU 1's blocks)."""
        if self._stream is not None:
            self._stream.synchronize()
        self._pinned = None
        self._stream = None
        self._tables = None
        self._gpu_kernel = None
        self._events = None
        cupy = self._cp
        if cupy is not None and self._device is not None:
            with self._device:
                cupy.get_default_memory_pool().free_all_blocks()
            cupy.get_default_pinned_memory_pool().free_all_blocks()

    def info(self) -> dict[str, Any]:
        params = self.config.detector
        return {
            'engine': 'cupy',
            'classes': [
                {
                    'class_index': i,
                    'name': c.name,
                    'ranges': [[list(lo), list(hi)] for lo, hi in c.ranges],
                }
                for i, c in enumerate(self.config.classes)
            ],
            'detector': {
                'min_area': params.min_area,
                'kernel': params.kernel,
                'open_iterations': params.open_iterations,
                'close_iterations': params.close_iterations,
            },
            'blobs': 'outer blobs: 8-connected components, holes filled; contour area estimated as '
            'filled - boundary/2 - 1',
            'timing': 'host: from the previous stage end, stream synchronised at every stage end; '
            'device: a start event before the first and an end event after the last GPU call '
            'of each stage, on the stream (frames.csv *_device_ms)',
            **self._facts,
        }

    def _warm_up(self) -> None:
        """One whole frame with a blob of every class (``warmup_image``) through every step:
        CuPy compiles its kernels, labelling and statistics included, before the first real
        frame. ``warmup_detections`` in ``info()`` says how many blobs it found."""
        began = time.perf_counter_ns()
        result = self._run(warmup_image(self.config), 0)
        self._facts['warmup_ms'] = (time.perf_counter_ns() - began) / 1e6
        self._facts['warmup_detections'] = len(result.detections)

    def _masks(self, planes: tuple[Any, Any, Any]) -> Any:
        params = self.config.detector
        return _hsv_ops.class_masks(
            self._cp,
            self._ndi,
            planes,
            self.config.classes,
            self._gpu_kernel,
            params.open_iterations,
            params.close_iterations,
        )

    def _stage(self, pixels: npt.NDArray[np.uint8]) -> Any:
        """The host side of the upload: the pixels copied into the reused pinned buffer."""
        pinned = self._pinned
        if pinned is None or pinned.shape != pixels.shape:
            cupyx = importlib.import_module('cupyx')
            pinned = self._pinned = cupyx.empty_pinned(pixels.shape, dtype=np.uint8)
        np.copyto(pinned, pixels)
        return pinned

    def _transfer(self, pinned: Any) -> Any:
        """The pinned pixels copied to the device, queued on the backend's stream."""
        gpu = self._cp.empty(pinned.shape, dtype=self._cp.uint8)
        gpu.set(pinned, stream=self._stream)
        return gpu

    def detect(self, frame: Frame) -> BackendResult:
        if self._stream is None or self._tables is None:
            self.open()
        pixels, blue = frame_pixels(frame)
        return self._run(pixels, blue)

    def _run(self, pixels: npt.NDArray[np.uint8], blue: int) -> BackendResult:
        cp, ndi, tables = self._cp, self._ndi, self._tables
        clock = StageClock(self._stream.synchronize, self._events)
        with self._device, self._stream:
            clock.start()
            pinned = self._stage(pixels)
            clock.begin()
            image = self._transfer(pinned)
            h2d = clock.lap()
            clock.begin()
            planes = _hsv_ops.to_hsv(cp, image, blue, tables)
            pre = clock.lap()
            clock.begin()
            masks = self._masks(planes)
            infer = clock.lap()
            clock.begin()
            stats = _hsv_ops.blob_stats(cp, ndi, masks, planes[1])
            post_device = clock.lap()
            clock.begin()
            rows = stats.get(stream=self._stream)
            d2h = clock.lap()
        on_device = clock.device_laps()
        t0 = time.perf_counter_ns()
        detections = detections_from_stats(np.asarray(rows, dtype=np.float64), self.config)
        post_host = time.perf_counter_ns() - t0
        stages = StageTimes(
            preprocess_ns=pre,
            infer_ns=infer,
            postprocess_ns=post_device + post_host,
            h2d_ns=h2d,
            d2h_ns=d2h,
            preprocess_device_ns=on_device[1],
            infer_device_ns=on_device[2],
            postprocess_device_ns=on_device[3],
            h2d_device_ns=on_device[0],
            d2h_device_ns=on_device[4],
        )
        return BackendResult(detections, stages)


def _cupy_cuda_version(cupy: Any) -> str:
    version = int(cupy.cuda.runtime.runtimeGetVersion())
    return f'{version // 1000}.{version % 1000 // 10}'
