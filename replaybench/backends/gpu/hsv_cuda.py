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
from replaybench.backends.gpu._cuda import StageClock, device_facts, driver_problem
from replaybench.backends.gpu.availability import hsv_cuda_availability
from replaybench.backends.hsv import HsvBackend, blob_score
from replaybench.decode import to_bgr8
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.types import BackendResult, Detection, StageTimes

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.backends.hsv import HsvConfig
    from replaybench.types import Frame

__all__ = ['HsvCudaBackend', 'detections_from_stats', 'frame_pixels', 'morphology_kernel']

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
        self._facts: dict[str, Any] = {}

    @classmethod
    def available(cls) -> Availability:
        return hsv_cuda_availability()

    def open(self) -> None:
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
            raise BackendUnavailableError(msg) from None
        self._cp, self._ndi = cupy, ndimage
        self._device = cupy.cuda.Device(index)
        try:
            with self._device:
                self._stream = cupy.cuda.Stream(non_blocking=True)
                sdiv, hdiv = _hsv_ops.hsv_tables()
                self._tables = (cupy.asarray(sdiv), cupy.asarray(hdiv))
                self._gpu_kernel = None if self._kernel is None else cupy.asarray(self._kernel)
                self._warm_up()
        except Exception as exc:  # missing CUDA runtime parts (NVRTC, ...) show up here
            self.close()
            msg = f'hsv-cuda: CuPy cannot run its kernels: {type(exc).__name__}: {exc}'
            raise BackendUnavailableError(msg) from None
        facts = device_facts(index)
        self._facts = {
            'device': index,
            'device_name': facts.name,
            'driver': facts.driver,
            'cuda_version': _cupy_cuda_version(cupy),
            'device_memory_bytes': facts.total_memory_bytes,
            'cupy': str(cupy.__version__),
        }

    def close(self) -> None:
        self._pinned = None
        self._stream = None
        self._tables = None
        self._gpu_kernel = None

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
            'timing': 'stream synchronised at every stage boundary',
            **self._facts,
        }

    def _warm_up(self) -> None:
        """Every step once on a tiny frame: compiles CuPy's kernels before the first real one."""
        pixels = np.zeros((8, 8, 3), dtype=np.uint8)
        pixels[2:6, 2:6] = (0, 0, 220)
        with self._stream:
            planes = _hsv_ops.to_hsv(self._cp, self._upload(pixels), 0, self._tables)
            _hsv_ops.blob_stats(self._cp, self._ndi, self._masks(planes), planes[1]).get()
        self._stream.synchronize()

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

    def _upload(self, pixels: npt.NDArray[np.uint8]) -> Any:
        cp = self._cp
        pinned = self._pinned
        if pinned is None or pinned.shape != pixels.shape:
            cupyx = importlib.import_module('cupyx')
            pinned = self._pinned = cupyx.empty_pinned(pixels.shape, dtype=np.uint8)
        np.copyto(pinned, pixels)
        gpu = cp.empty(pixels.shape, dtype=cp.uint8)
        gpu.set(pinned, stream=self._stream)
        return gpu

    def detect(self, frame: Frame) -> BackendResult:
        if self._stream is None or self._tables is None:
            self.open()
        cp, ndi, tables = self._cp, self._ndi, self._tables
        pixels, blue = frame_pixels(frame)
        clock = StageClock(self._stream.synchronize)
        with self._device, self._stream:
            clock.start()
            image = self._upload(pixels)
            h2d = clock.lap()
            planes = _hsv_ops.to_hsv(cp, image, blue, tables)
            pre = clock.lap()
            masks = self._masks(planes)
            infer = clock.lap()
            stats = _hsv_ops.blob_stats(cp, ndi, masks, planes[1])
            post_device = clock.lap()
            rows = stats.get(stream=self._stream)
            d2h = clock.lap()
        t0 = time.perf_counter_ns()
        detections = detections_from_stats(np.asarray(rows, dtype=np.float64), self.config)
        post_host = time.perf_counter_ns() - t0
        stages = StageTimes(
            preprocess_ns=pre,
            infer_ns=infer,
            postprocess_ns=post_device + post_host,
            h2d_ns=h2d,
            d2h_ns=d2h,
        )
        return BackendResult(detections, stages)


def _cupy_cuda_version(cupy: Any) -> str:
    version = int(cupy.cuda.runtime.runtimeGetVersion())
    return f'{version // 1000}.{version % 1000 // 10}'
