"""HSV colour segmentation: a class id per pixel from the ``hsv`` backend's colour classes.

The configuration is the ``hsv`` backend's (``--config`` TOML, the same ``[[classes]]`` and
``[detector]`` keys; ``min_area`` is read and has no effect here): class id 0 is
``background``, class ``k`` of the configuration is id ``k + 1``. A class's mask is the union
of its HSV ranges, cleaned by the same open and close with the same elliptic kernel as
``hsv``; a pixel takes the first class (configuration order) whose cleaned mask holds it, and
0 when none does.

Per frame: one conversion to HSV (``preprocess``); the H, S and V planes, each through a
256-entry ``cv2.LUT`` that sets one bit per range the value lies in, AND-ed (bit ``r`` of a
pixel is set when it lies in range ``r``; eight ranges to a byte); the OR of those bits over
16x16 tiles says which tiles hold which classes. Per class, only on the boxes of its tiles
grown by one tile (a tile is longer than the morphology's reach) plus the reach: one
256-entry ``cv2.LUT`` from the range bits to its 0/1 mask and the open / close (``infer``).
The label mask is written from the cleaned masks, last class first (``postprocess``).
``benchmarks/naive_hsv_seg.py`` is the straightforward per-class port (``cv2.inRange`` per
range, full-frame morphology, boolean indexing); both give the same mask
(tests/backends/test_hsv_seg.py), and ``benchmarks/bench_segmentation.py`` times them.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, ClassVar, cast

import numpy as np

from replaybench.backends.base import BackendOptions
from replaybench.backends.hsv import ColourMorphology, HsvConfig, _apply_extra, load_config
from replaybench.errors import BackendError
from replaybench.types import BackendResult, LabelMask, StageTimes

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.types import Frame

__all__ = ['BACKGROUND', 'HsvSegBackend', 'seg_class_names']

#: Name of class id 0.
BACKGROUND = 'background'


def seg_class_names(config: HsvConfig) -> tuple[str, ...]:
    """Class names by id: ``background``, then the configuration's classes in order."""
    return (BACKGROUND, *(cls.name for cls in config.classes))


class _Plan:
    """The lookup tables of one configuration: range bits per channel, class masks per group.

    Ranges are numbered in configuration order and packed eight to a byte (a ``group``); each
    group has a ``[1, 256, 3]`` table (H, S, V bits), and each class one 256-entry table per
    group it has ranges in (1 where any of its bits is set: a mask of 0 / 1 reads as bool).
    """

    def __init__(self, config: HsvConfig) -> None:
        ranges = [(index, r) for index, cls in enumerate(config.classes) for r in cls.ranges]
        groups = (len(ranges) + 7) // 8
        self.channel_luts = [np.zeros((1, 256, 3), dtype=np.uint8) for _ in range(groups)]
        values = np.arange(256)
        class_bits = [[0] * groups for _ in config.classes]
        for number, (index, (lower, upper)) in enumerate(ranges):
            group, bit = divmod(number, 8)
            lut = self.channel_luts[group]
            for channel in range(3):
                inside = (values >= lower[channel]) & (values <= upper[channel])
                lut[0, inside, channel] |= np.uint8(1 << bit)
            class_bits[index][group] |= 1 << bit
        self.plane_luts = [
            [np.ascontiguousarray(lut[:, :, channel]) for channel in range(3)]
            for lut in self.channel_luts
        ]
        self.class_luts: list[list[tuple[int, npt.NDArray[np.uint8]]]] = []
        for bits in class_bits:
            tables = []
            for group, mask in enumerate(bits):
                if mask:
                    table = np.where(values & mask, 1, 0).astype(np.uint8)
                    tables.append((group, table.reshape(1, 256)))
            self.class_luts.append(tables)


#: Side of the square tiles whose class occupancy bounds the per-class work, pixels.
_TILE = 16
_GROW = np.ones((3, 3), dtype=np.uint8)


def _tile_or(bits: npt.NDArray[np.uint8], tile: int) -> npt.NDArray[np.uint8]:
    """The OR of ``bits`` over each ``tile x tile`` tile (edge tiles may be smaller)."""
    height, width = bits.shape
    rows_full, cols_full = height // tile, width // tile
    n_rows, n_cols = -(-height // tile), -(-width // tile)
    rows = np.empty((n_rows, width), dtype=np.uint8)
    if rows_full:
        stacked = bits[: rows_full * tile].reshape(rows_full, tile, width)
        np.bitwise_or.reduce(stacked, axis=1, out=rows[:rows_full])
    if rows_full < n_rows:
        np.bitwise_or.reduce(bits[rows_full * tile :], axis=0, out=rows[rows_full])
    out = np.empty((n_rows, n_cols), dtype=np.uint8)
    if cols_full:
        stacked = rows[:, : cols_full * tile].reshape(n_rows, cols_full, tile)
        np.bitwise_or.reduce(stacked, axis=2, out=out[:, :cols_full])
    if cols_full < n_cols:
        np.bitwise_or.reduce(rows[:, cols_full * tile :], axis=1, out=out[:, cols_full])
    return out


def _boxes(
    tiles: list[npt.NDArray[np.uint8]],
    tables: list[tuple[int, npt.NDArray[np.uint8]]],
    tile: int,
    width: int,
    height: int,
) -> list[tuple[int, int, int, int]]:
    """Pixel boxes ``(x0, y0, x1, y1)`` that hold every pixel a class's cleaned mask can have.

    The tiles with a pixel of the class, grown by one tile (a tile is longer than the
    morphology's reach), grouped into 8-connected regions; each region's bounding box.
    """
    import cv2

    group, table = tables[0]
    active = table[0][tiles[group]]
    for group, table in tables[1:]:
        np.bitwise_or(active, table[0][tiles[group]], out=active)
    if not active.any():
        return []
    grown = cv2.dilate(active, _GROW)
    count, _, stats, _ = cv2.connectedComponentsWithStats(grown, connectivity=8)
    rows = stats[1:count].tolist()
    covered = sum(row[4] for row in rows)
    left, top = min(row[0] for row in rows), min(row[1] for row in rows)
    right = max(row[0] + row[2] for row in rows)
    bottom = max(row[1] + row[3] for row in rows)
    if len(rows) > 1 and 2 * covered >= (right - left) * (bottom - top):
        rows = [[left, top, right - left, bottom - top, covered]]  # one call beats several
    boxes = []
    for left, top, w, h, _area in rows:
        x0, y0 = left * tile, top * tile
        boxes.append((x0, y0, min((left + w) * tile, width), min((top + h) * tile, height)))
    return boxes


class _Buffers:
    def __init__(self, height: int, width: int, groups: int) -> None:
        self.shape = (height, width)
        self.hsv = np.empty((height, width, 3), dtype=np.uint8)
        self.hsv_planes = [np.empty((height, width), dtype=np.uint8) for _ in range(3)]
        self.planes = [np.empty((height, width), dtype=np.uint8) for _ in range(3)]
        self.bits = [np.empty((height, width), dtype=np.uint8) for _ in range(groups)]


class HsvSegBackend(ColourMorphology):
    """Per-pixel colour classes with OpenCV; configured exactly as the ``hsv`` backend.

    ``options.extra`` may override ``[detector]`` keys (``kernel``, ``open_iterations``,
    ``close_iterations``, ``min_area``). ``options.threads`` sets ``cv2.setNumThreads`` while
    the backend is open. Returns ``BackendResult.mask``; no detections.
    """

    name: ClassVar[str] = 'hsv-seg'
    description: ClassVar[str] = (
        'OpenCV HSV colour segmentation: per-pixel class ids, hsv config and morphology (CPU)'
    )

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        config = load_config(self.options.config) if self.options.config else HsvConfig()
        try:
            self.config = _apply_extra(config, self.options.extra)
        except BackendError as exc:
            msg = str(exc).replace('hsv:', 'hsv-seg:', 1)
            raise BackendError(msg) from exc
        if len(self.config.classes) > 255:
            msg = 'hsv-seg: at most 255 colour classes fit a uint8 mask'
            raise BackendError(msg)
        self.class_names = seg_class_names(self.config)
        params = self.config.detector
        self._morph = params.kernel > 1 and (params.open_iterations + params.close_iterations) > 0
        radius = params.kernel // 2
        # how far the open and close carry a pixel's value (erosions and dilations of radius r)
        self._reach = 2 * radius * (params.open_iterations + params.close_iterations)
        self._tile = max(_TILE, self._reach + 1)
        self._plan = _Plan(self.config)
        self._kernel: npt.NDArray[np.uint8] | None = None
        self._saved_threads: int | None = None
        self._buffers: _Buffers | None = None

    def info(self) -> dict[str, Any]:
        params = self.config.detector
        facts: dict[str, Any] = {
            'task': 'segmentation',
            'config': str(self.options.config) if self.options.config else None,
            'class_names': list(self.class_names),
            'classes': [
                {
                    'class_id': index + 1,
                    'name': cls.name,
                    'ranges': [[list(lo), list(hi)] for lo, hi in cls.ranges],
                }
                for index, cls in enumerate(self.config.classes)
            ],
            'morphology': {
                'kernel': params.kernel,
                'open_iterations': params.open_iterations,
                'close_iterations': params.close_iterations,
            },
            'overlap': 'first class in configuration order',
            'threads': self.options.threads,
        }
        if self._kernel is not None:
            import cv2

            facts['opencv'] = cv2.__version__
        return facts

    def _hsv(self, frame: Frame) -> npt.NDArray[np.uint8]:
        import cv2

        image, code = self._colour_source(frame)
        height, width = int(image.shape[0]), int(image.shape[1])
        buffers = self._buffers
        if buffers is None or buffers.shape != (height, width):
            groups = len(self._plan.channel_luts)
            buffers = _Buffers(height, width, groups)
            self._buffers = buffers
        cv2.cvtColor(image, code, dst=buffers.hsv)
        return buffers.hsv

    def detect(self, frame: Frame) -> BackendResult:
        import cv2

        if self._kernel is None:
            self.open()
        kernel = cast('npt.NDArray[np.uint8]', self._kernel)
        params = self.config.detector
        clock = time.perf_counter_ns

        t0 = clock()
        hsv = self._hsv(frame)
        t1 = clock()

        buffers = cast('_Buffers', self._buffers)
        height, width = buffers.shape
        h_plane, s_plane, v_plane = buffers.planes
        tiles = []
        cv2.split(hsv, buffers.hsv_planes)
        for luts, bits in zip(self._plan.plane_luts, buffers.bits, strict=True):
            for plane, lut, out in zip(buffers.hsv_planes, luts, buffers.planes, strict=True):
                cv2.LUT(plane, lut, dst=out)
            cv2.bitwise_and(h_plane, s_plane, dst=bits)
            cv2.bitwise_and(bits, v_plane, dst=bits)
            tiles.append(_tile_or(bits, self._tile))
        cleaned: list[tuple[int, tuple[int, int, int, int], npt.NDArray[np.uint8]]] = []
        reach = self._reach
        tile = self._tile
        for index, tables in enumerate(self._plan.class_luts):
            for x0, y0, x1, y1 in _boxes(tiles, tables, tile, width, height):
                # the mask and its morphology on the box plus the morphology's reach: exact
                # inside the box, which holds every pixel of the class's cleaned mask
                rx0, ry0 = max(x0 - reach, 0), max(y0 - reach, 0)
                rx1, ry1 = min(x1 + reach, width), min(y1 + reach, height)
                group, table = tables[0]
                region = cast(
                    'npt.NDArray[np.uint8]', cv2.LUT(buffers.bits[group][ry0:ry1, rx0:rx1], table)
                )
                for group, table in tables[1:]:
                    part = cv2.LUT(buffers.bits[group][ry0:ry1, rx0:rx1], table)
                    cv2.bitwise_or(region, part, dst=region)
                if self._morph and params.open_iterations:
                    cv2.morphologyEx(
                        region,
                        cv2.MORPH_OPEN,
                        kernel,
                        dst=region,
                        iterations=params.open_iterations,
                    )
                if self._morph and params.close_iterations:
                    cv2.morphologyEx(
                        region,
                        cv2.MORPH_CLOSE,
                        kernel,
                        dst=region,
                        iterations=params.close_iterations,
                    )
                inner = region[y0 - ry0 : y1 - ry0, x0 - rx0 : x1 - rx0]
                cleaned.append((index, (x0, y0, x1, y1), inner))
        t2 = clock()

        labels = np.zeros((height, width), dtype=np.uint8)
        for index, (x0, y0, x1, y1), inner in reversed(cleaned):
            np.copyto(labels[y0:y1, x0:x1], np.uint8(index + 1), where=inner.view(np.bool_))
        t3 = clock()
        return BackendResult(
            (),
            StageTimes(preprocess_ns=t1 - t0, infer_ns=t2 - t1, postprocess_ns=t3 - t2),
            LabelMask(labels, self.class_names),
        )
