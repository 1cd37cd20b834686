"""HSV colour segmentation: a class id per pixel from the ``hsv`` backend's colour classes.

The configuration is the ``hsv`` backend's (``--config`` TOML, the same ``[[classes]]`` and
``[detector]`` keys; ``min_area`` is read and has no effect here): class id 0 is
``background``, class ``k`` of the configuration is id ``k + 1``. A class's mask is the union
of its HSV ranges, cleaned by the same open and close with the same elliptic kernel as
``hsv``; a pixel takes the first class (configuration order) whose cleaned mask holds it, and
0 when none does.

Per frame: one conversion to HSV (``preprocess``). Then the range bits of every pixel (bit
``r`` set when the pixel lies in range ``r``; eight ranges to a byte): per H, S and V plane
either one ``cv2.threshold`` / ``cv2.inRange`` (when every range of the byte has the same
interval on that channel, as the default classes have on S and V) or a 256-entry ``cv2.LUT``
that sets the bits of the ranges holding the value; the planes' results AND-ed. The OR of
those bits over 16x16 tiles says which tiles hold which classes; one connected-component
labelling of all classes' tiles gives each class's boxes (its 8-connected groups of tiles),
grown by the close's reach (no cleaned pixel lies farther from a pixel of the class). Only on
those boxes plus the whole morphology's reach (so that the box is exact): the class's bits
(an AND with its range bits), every region side by side on one canvas, and the open / close
of the canvas in one erode, dilate and erode (``infer``). The label mask is written from the
cleaned masks, last class first, one masked ``cv2.copyTo`` per box (``postprocess``).
``benchmarks/naive_hsv_seg.py`` is the straightforward per-class port (``cv2.inRange`` per
range, full-frame morphology, boolean indexing); both give the same mask
(tests/backends/test_hsv_seg.py), and ``benchmarks/bench_segmentation.py`` times them.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, cast

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


class _ChannelTest(NamedTuple):
    """How one H, S or V plane gives its part of a group's range bits.

    ``lut`` (a ``[1, 256]`` table of the bits of the ranges holding each value) when the
    group's ranges differ on this channel; else None and the one interval ``lower..upper``
    they share, tested for 255 (all bits) inside and 0 outside.
    """

    channel: int
    lut: npt.NDArray[np.uint8] | None
    lower: int
    upper: int

    def apply(self, plane: npt.NDArray[np.uint8], out: npt.NDArray[np.uint8]) -> None:
        import cv2

        if self.lut is not None:
            cv2.LUT(plane, self.lut, dst=out)
        elif self.upper == 255:
            cv2.threshold(plane, self.lower - 1, 255, cv2.THRESH_BINARY, dst=out)
        elif self.lower == 0:
            cv2.threshold(plane, self.upper, 255, cv2.THRESH_BINARY_INV, dst=out)
        else:
            cv2.inRange(plane, self.lower, self.upper, dst=out)


def _channel_test(channel: int, table: npt.NDArray[np.uint8]) -> _ChannelTest | None:
    """The cheapest exact test of one channel's bits table; None when every value passes."""
    every = int(np.bitwise_or.reduce(table))
    if not bool(np.all((table == 0) | (table == every))):
        return _ChannelTest(channel, np.ascontiguousarray(table.reshape(1, 256)), 0, 0)
    inside = np.flatnonzero(table)  # one interval: every range of the group has this one
    lower, upper = int(inside[0]), int(inside[-1])
    if lower == 0 and upper == 255:
        return None
    return _ChannelTest(channel, None, lower, upper)


class _Plan:
    """The tests of one configuration: range bits per group, class bits per group.

    Ranges are numbered in configuration order and packed eight to a byte (a ``group``); each
    group has the tests of the channels that narrow it (see ``_ChannelTest``; bits of a byte
    that no range uses may be set by an interval test, and no class reads them), never none
    (hue bounds end at 180, so H 181..255 is outside every range), and each class the
    ``(group, bits)`` pairs it has ranges in.
    """

    def __init__(self, config: HsvConfig) -> None:
        ranges = [(index, r) for index, cls in enumerate(config.classes) for r in cls.ranges]
        groups = (len(ranges) + 7) // 8
        tables = [np.zeros((3, 256), dtype=np.uint8) for _ in range(groups)]
        class_bits = [[0] * groups for _ in config.classes]
        for number, (index, (lower, upper)) in enumerate(ranges):
            group, bit = divmod(number, 8)
            for channel in range(3):
                tables[group][channel, lower[channel] : upper[channel] + 1] |= np.uint8(1 << bit)
            class_bits[index][group] |= 1 << bit
        self.tests = [
            [t for t in (_channel_test(c, table[c]) for c in range(3)) if t is not None]
            for table in tables
        ]
        self.class_bits = [
            [(group, np.uint8(mask)) for group, mask in enumerate(bits) if mask]
            for bits in class_bits
        ]
        #: Per group, every class's bits in it (0 where the class has no range there).
        self.group_masks = [
            np.array([bits[group] for bits in class_bits], dtype=np.uint8)
            for group in range(groups)
        ]


#: Side of the square tiles whose class occupancy bounds the per-class work, pixels.
_TILE = 16
#: Pixels of morphology a class's boxes may take on to spare the calls of one more box (a
#: box's calls cost about as much as this many pixels' open and close).
_MERGE_PIXELS = 8192


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


def _class_boxes(
    tiles: list[npt.NDArray[np.uint8]],
    group_masks: list[npt.NDArray[np.uint8]],
    grow: int,
    width: int,
    height: int,
) -> list[list[tuple[int, int, int, int]]]:
    """Per class, pixel boxes ``(x0, y0, x1, y1)`` that hold every pixel its cleaned mask can
    have.

    Each class's tiles with a pixel of it, side by side with a column of empty tiles between
    two classes, go through one connected-component labelling; the bounding box of each
    8-connected group, grown by ``grow`` pixels (the open never adds a pixel, the close adds
    none farther than its dilations reach), is a box of its class. A class's boxes become
    one around them all when that costs fewer than ``_MERGE_PIXELS`` more pixels per box it
    spares.
    """
    import cv2

    n_rows, n_cols = tiles[0].shape
    classes = len(group_masks[0])
    stride = n_cols + 1
    active = np.zeros((n_rows, classes, stride), dtype=np.uint8)
    view = active[:, :, :n_cols]
    np.bitwise_and(tiles[0][:, None, :], group_masks[0][None, :, None], out=view)
    for group_tiles, masks in zip(tiles[1:], group_masks[1:], strict=True):
        np.bitwise_or(view, group_tiles[:, None, :] & masks[None, :, None], out=view)
    flat = active.reshape(n_rows, classes * stride)
    # Grana's algorithm: a half of the default's time at this size with int32 labels
    count, _, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(
        flat, 8, cv2.CV_32S, cv2.CCL_GRANA
    )
    found: list[list[tuple[int, int, int, int]]] = [[] for _ in range(classes)]
    for left, top, w, h, _area in stats[1:count].tolist():
        index, x = divmod(left, stride)
        found[index].append(
            (
                max(x * _TILE - grow, 0),
                max(top * _TILE - grow, 0),
                min((x + w) * _TILE + grow, width),
                min((top + h) * _TILE + grow, height),
            )
        )
    return [_merged(boxes) for boxes in found]


def _merged(boxes: list[tuple[int, int, int, int]]) -> list[tuple[int, int, int, int]]:
    """``boxes``, or one box around them all when that costs fewer than ``_MERGE_PIXELS``
    more pixels per box it spares."""
    if len(boxes) < 2:
        return boxes
    x0, y0 = min(b[0] for b in boxes), min(b[1] for b in boxes)
    x1, y1 = max(b[2] for b in boxes), max(b[3] for b in boxes)
    parts = sum((b[2] - b[0]) * (b[3] - b[1]) for b in boxes)
    if (x1 - x0) * (y1 - y0) - parts <= _MERGE_PIXELS * (len(boxes) - 1):
        return [(x0, y0, x1, y1)]
    return boxes


class _Slot(NamedTuple):
    """One box of a class's cleaned mask and the region its morphology needs: the box
    grown by the morphology's reach (``x0, y0, x1, y1``, frame pixels)."""

    class_index: int
    box: tuple[int, int, int, int]
    region: tuple[int, int, int, int]


def _layout(
    regions: list[tuple[int, int, int, int]], width: int, height: int
) -> tuple[list[tuple[int, int, int]], list[int], int, int]:
    """Regions side by side on one canvas: ``(number, x, y)`` of those placed, the numbers
    of those left alone, the canvas's height and width.

    A region on the frame's left edge goes first, one on its right edge last (one of each;
    any other such region, and one as wide as the frame, is left alone); one on the frame's
    bottom edge (and not its top) at the canvas's bottom, any other at its top.
    """
    left: list[int] = []
    middle: list[int] = []
    right: list[int] = []
    alone: list[int] = []
    for number, (x0, _, x1, _) in enumerate(regions):
        if x0 == 0 and x1 == width:
            alone.append(number)
        elif x0 == 0:
            (alone if left else left).append(number)
        elif x1 == width:
            (alone if right else right).append(number)
        else:
            middle.append(number)
    row = left + middle + right
    canvas_h = max((regions[n][3] - regions[n][1] for n in row), default=0)
    placed = []
    x = 0
    for number in row:
        x0, y0, x1, y1 = regions[number]
        y = canvas_h - (y1 - y0) if y1 == height and y0 > 0 else 0
        placed.append((number, x, y))
        x += x1 - x0
    return placed, alone, canvas_h, x


class _Buffers:
    def __init__(self, height: int, width: int, groups: int) -> None:
        self.shape = (height, width)
        self.hsv = np.empty((height, width, 3), dtype=np.uint8)
        self.hsv_planes = [np.empty((height, width), dtype=np.uint8) for _ in range(3)]
        self.part = np.empty((height, width), dtype=np.uint8)
        self.bits = [np.empty((height, width), dtype=np.uint8) for _ in range(groups)]
        #: Filled with a class id on a box before that box's ids are copied into the mask.
        self.ids = np.empty((height, width), dtype=np.uint8)
        self._canvas = np.empty(height * width, dtype=np.uint8)

    def canvas(self, height: int, width: int) -> npt.NDArray[np.uint8]:
        """A ``height x width`` work image (its memory reused from frame to frame)."""
        if self._canvas.size < height * width:
            self._canvas = np.empty(height * width, dtype=np.uint8)
        return self._canvas[: height * width].reshape(height, width)


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
    #: Its results carry a label mask (``Backend.task``).
    task: ClassVar[str] = 'segmentation'

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
        # how far the close's dilations carry a pixel: no cleaned pixel lies farther from one
        # of the class (the open only removes pixels)
        self._grow = radius * params.close_iterations if self._morph else 0
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
            groups = len(self._plan.tests)
            buffers = _Buffers(height, width, groups)
            self._buffers = buffers
        cv2.cvtColor(image, code, dst=buffers.hsv)
        return buffers.hsv

    def _morphology(self, image: npt.NDArray[np.uint8]) -> None:
        """The open and close of ``image`` in place: the erosions and dilations that
        ``cv2.morphologyEx`` makes, with the open's and the close's dilations in one call."""
        import cv2

        if not self._morph:
            return
        kernel = cast('npt.NDArray[np.uint8]', self._kernel)
        params = self.config.detector
        opens, closes = params.open_iterations, params.close_iterations
        if opens:
            cv2.erode(image, kernel, dst=image, iterations=opens)
        cv2.dilate(image, kernel, dst=image, iterations=opens + closes)
        if closes:
            cv2.erode(image, kernel, dst=image, iterations=closes)

    def _clean(self, slots: list[_Slot], buffers: _Buffers) -> list[npt.NDArray[np.uint8]]:
        """Each slot's cleaned mask on its box (non-zero: the class's pixel).

        A slot's mask is its class's range bits (0 outside the class, not 0 / 1: an erosion
        or dilation of it is non-zero exactly where that of the 0 / 1 mask is). The regions
        lie side by side on one canvas, so that the morphology runs once on all of them (its
        cost is mostly per call and per row): a region's box is at least the reach away
        from every side of it that is inside the frame, so what lies beyond such a side
        cannot change the box; a side on the frame's edge is put on the canvas's same edge,
        where OpenCV's border stands in for the frame's. Regions that cannot be put there
        (a second one on the frame's left or right edge) get an image of their own. The
        canvas above or below a region shorter than it keeps what it held: that lies
        beyond a side inside the frame, farther than the reach from every box.
        """
        height, width = buffers.shape
        placed, alone, canvas_h, canvas_w = _layout([s.region for s in slots], width, height)
        canvas = buffers.canvas(canvas_h, canvas_w)
        origins: dict[int, tuple[npt.NDArray[np.uint8], int, int]] = {}
        for number, x, y in placed:
            rx0, ry0, rx1, ry1 = slots[number].region
            w, h = rx1 - rx0, ry1 - ry0
            self._class_mask(slots[number], buffers, canvas[y : y + h, x : x + w])
            origins[number] = (canvas, x, y)
        if placed:
            self._morphology(canvas)
        for number in alone:
            rx0, ry0, rx1, ry1 = slots[number].region
            image = np.empty((ry1 - ry0, rx1 - rx0), dtype=np.uint8)
            self._class_mask(slots[number], buffers, image)
            self._morphology(image)
            origins[number] = (image, 0, 0)
        cleaned = []
        for number, slot in enumerate(slots):
            image, x, y = origins[number]
            x0, y0, x1, y1 = slot.box
            rx0, ry0 = slot.region[:2]
            cleaned.append(image[y + y0 - ry0 : y + y1 - ry0, x + x0 - rx0 : x + x1 - rx0])
        return cleaned

    def _class_mask(self, slot: _Slot, buffers: _Buffers, out: npt.NDArray[np.uint8]) -> None:
        """The slot's class's range bits on its region, into ``out``."""
        rx0, ry0, rx1, ry1 = slot.region
        class_bits = self._plan.class_bits[slot.class_index]
        group, mask = class_bits[0]
        np.bitwise_and(buffers.bits[group][ry0:ry1, rx0:rx1], mask, out=out)
        for group, mask in class_bits[1:]:
            part = np.bitwise_and(buffers.bits[group][ry0:ry1, rx0:rx1], mask)
            np.bitwise_or(out, part, out=out)

    def detect(self, frame: Frame) -> BackendResult:
        import cv2

        if self._kernel is None:
            self.open()
        clock = time.perf_counter_ns

        t0 = clock()
        hsv = self._hsv(frame)
        t1 = clock()

        buffers = cast('_Buffers', self._buffers)
        height, width = buffers.shape
        planes = buffers.hsv_planes
        plan = self._plan
        cv2.split(hsv, planes)
        tiles = []
        for tests, bits in zip(plan.tests, buffers.bits, strict=True):
            first, *others = tests
            first.apply(planes[first.channel], bits)
            for test in others:
                test.apply(planes[test.channel], buffers.part)
                cv2.bitwise_and(bits, buffers.part, dst=bits)
            tiles.append(_tile_or(bits, _TILE))
        reach = self._reach
        slots: list[_Slot] = []
        boxes = _class_boxes(tiles, plan.group_masks, self._grow, width, height)
        for index, class_boxes in enumerate(boxes):
            for x0, y0, x1, y1 in class_boxes:
                # the class's mask and its morphology on the box plus the morphology's reach:
                # exact inside the box, which holds every pixel of the class's cleaned mask
                region = (
                    max(x0 - reach, 0),
                    max(y0 - reach, 0),
                    min(x1 + reach, width),
                    min(y1 + reach, height),
                )
                slots.append(_Slot(index, (x0, y0, x1, y1), region))
        cleaned = self._clean(slots, buffers)
        t2 = clock()

        labels = np.zeros((height, width), dtype=np.uint8)
        for slot, inner in zip(reversed(slots), reversed(cleaned), strict=True):
            x0, y0, x1, y1 = slot.box
            ids = buffers.ids[y0:y1, x0:x1]
            ids.fill(slot.class_index + 1)
            cv2.copyTo(ids, inner, dst=labels[y0:y1, x0:x1])
        t3 = clock()
        return BackendResult(
            (),
            StageTimes(preprocess_ns=t1 - t0, infer_ns=t2 - t1, postprocess_ns=t3 - t2),
            LabelMask(labels, self.class_names),
        )
