"""HSV colour-blob detector: the classic perception-lab node, with one colour conversion per frame.

Per frame: convert to HSV once (``preprocess``); per colour class the mask of pixels inside
any of its ranges (red: two ranges, one each side of the hue wrap-around), then a morphological
open and close with an elliptic kernel (``infer``); external contours, a minimum contour area,
bounding boxes and scores (``postprocess``). The masks come from one ``cv2.inRange`` per
distinct hue interval (H plane) and per distinct S/V box, AND-ed; morphology runs in place on
the bounding box of a class's pixels plus the kernel's reach; work images are reused across
frames. ``benchmarks/naive_hsv.py`` is the unoptimised original; both give the same detections.

Score of a blob, from its own pixels::

    fill   = blob pixels / box area                       (1.0 for a solid rectangle)
    margin = clip((mean S of blob pixels - S floor) / (255 - S floor), 0, 1)
    score  = round(fill * (0.5 + 0.5 * margin), 6)

where the blob pixels are the class-mask pixels inside the filled contour and the S floor is
the smallest lower saturation bound of the class's ranges.
"""

from __future__ import annotations

import importlib.util
import json
import math
import time
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, cast

import numpy as np

from replaybench.backends.base import Availability, BackendOptions
from replaybench.decode import to_bgr8
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.types import BackendResult, Detection, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping

    import numpy.typing as npt

    from replaybench.types import Frame

__all__ = [
    'DEFAULT_CLASSES',
    'ColorClass',
    'DetectorParams',
    'HsvBackend',
    'HsvConfig',
    'HsvRange',
    'blob_score',
    'config_to_toml',
    'default_config_toml',
    'load_config',
    'parse_config',
]

Hsv = tuple[int, int, int]
#: Inclusive (lower, upper) HSV bounds; OpenCV 8-bit scale: H 0..180, S and V 0..255.
HsvRange = tuple[Hsv, Hsv]


class ColorClass(NamedTuple):
    """One colour class: its label and the HSV ranges whose union it is."""

    name: str
    ranges: tuple[HsvRange, ...]

    @property
    def saturation_floor(self) -> int:
        """The smallest lower S bound over the ranges; the zero point of the score margin."""
        return min(lower[1] for lower, _ in self.ranges)


#: Defaults: red, green, blue, yellow (class_index 0..3); S >= 100 and V >= 70 everywhere,
#: so grey, white and dark background pixels stay out of every mask.
DEFAULT_CLASSES: tuple[ColorClass, ...] = (
    ColorClass('red', (((0, 100, 70), (10, 255, 255)), ((170, 100, 70), (180, 255, 255)))),
    ColorClass('green', (((40, 100, 70), (85, 255, 255)),)),
    ColorClass('blue', (((100, 100, 70), (130, 255, 255)),)),
    ColorClass('yellow', (((20, 100, 70), (34, 255, 255)),)),
)


@dataclass(frozen=True, slots=True)
class DetectorParams:
    """The ``[detector]`` table.

    ``min_area``: smallest ``cv2.contourArea`` of a blob, px². ``kernel``: odd size of the
    elliptic morphology kernel (1 disables morphology). ``open_iterations`` /
    ``close_iterations``: how often the open (removes specks) and the close (fills small
    gaps) are applied; 0 skips that step.
    """

    min_area: float = 100.0
    kernel: int = 5
    open_iterations: int = 1
    close_iterations: int = 1


@dataclass(frozen=True, slots=True)
class HsvConfig:
    """Everything the hsv backend is configured by."""

    classes: tuple[ColorClass, ...] = DEFAULT_CLASSES
    detector: DetectorParams = field(default_factory=DetectorParams)


#: the [tracker.NAME] tables are a tracked backend's (replaybench.backends.tracked)
_TOP_KEYS = ('classes', 'detector', 'tracker')
_CLASS_KEYS = ('name', 'ranges')
_DETECTOR_KEYS = tuple(DetectorParams.__dataclass_fields__)
_COMPONENTS = (('hue', 180), ('saturation', 255), ('value', 255))


def _fail(source: str, where: str, what: str) -> BackendError:
    return BackendError(f'{source}: {where}: {what}')


def _check_keys(source: str, where: str, table: Mapping[str, Any], known: tuple[str, ...]) -> None:
    unknown = sorted(set(table) - set(known))
    if unknown:
        what = f'unknown key {unknown[0]!r} (known: {", ".join(sorted(known))})'
        raise _fail(source, where, what)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _parse_triple(source: str, where: str, value: object) -> Hsv:
    if not isinstance(value, list) or len(value) != 3 or not all(_is_int(v) for v in value):
        raise _fail(source, where, f'expected [H, S, V] with 3 integers, got {value!r}')
    for v, (component, top) in zip(value, _COMPONENTS, strict=True):
        if not 0 <= v <= top:
            raise _fail(source, where, f'{component} {v} is outside 0..{top}')
    return (value[0], value[1], value[2])


def _parse_range(source: str, where: str, value: object) -> HsvRange:
    if not isinstance(value, list) or len(value) != 2:
        raise _fail(source, where, f'expected [[H, S, V], [H, S, V]] (lower, upper), got {value!r}')
    lower = _parse_triple(source, f'{where}[0]', value[0])
    upper = _parse_triple(source, f'{where}[1]', value[1])
    for lo, hi, (component, _) in zip(lower, upper, _COMPONENTS, strict=True):
        if lo > hi:
            what = f'lower {component} {lo} > upper {component} {hi}'
            if component == 'hue':
                what += '; a range across the hue wrap-around must be split in two ranges'
            raise _fail(source, where, what)
    return (lower, upper)


def _parse_class(source: str, index: int, value: object) -> ColorClass:
    where = f'classes[{index}]'
    if not isinstance(value, dict):
        raise _fail(source, where, f'expected a [[classes]] table, got {value!r}')
    _check_keys(source, where, value, _CLASS_KEYS)
    name = value.get('name')
    if not isinstance(name, str) or not name.strip():
        raise _fail(source, f'{where}.name', f'expected a non-empty string, got {name!r}')
    ranges = value.get('ranges')
    if not isinstance(ranges, list) or not ranges:
        what = f'expected a non-empty list of [lower, upper] ranges, got {ranges!r}'
        raise _fail(source, f'{where}.ranges', what)
    parsed = tuple(
        _parse_range(source, f'{where}.ranges[{i}]', item) for i, item in enumerate(ranges)
    )
    return ColorClass(name, parsed)


def _number(source: str, where: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _fail(source, where, f'expected a finite number, got {value!r}')
    return float(value)


def _parse_detector(source: str, table: Mapping[str, Any]) -> DetectorParams:
    _check_keys(source, '[detector]', table, _DETECTOR_KEYS)
    params = DetectorParams()
    if 'min_area' in table:
        min_area = _number(source, '[detector] min_area', table['min_area'])
        if min_area < 0:
            raise _fail(source, '[detector] min_area', f'must be >= 0, got {min_area!r}')
        params = replace(params, min_area=min_area)
    if 'kernel' in table:
        kernel = table['kernel']
        if not _is_int(kernel) or kernel < 1 or kernel % 2 == 0:
            raise _fail(source, '[detector] kernel', f'must be an odd integer >= 1, got {kernel!r}')
        params = replace(params, kernel=kernel)
    for key in ('open_iterations', 'close_iterations'):
        if key in table:
            count = table[key]
            if not _is_int(count) or count < 0:
                raise _fail(source, f'[detector] {key}', f'must be an integer >= 0, got {count!r}')
            params = replace(params, **{key: count})
    return params


def parse_config(data: Mapping[str, Any], source: str = '<hsv config>') -> HsvConfig:
    """An ``HsvConfig`` from parsed TOML; ``BackendError`` naming source, key and problem.

    A missing ``[detector]`` table or key keeps the default; a missing ``[[classes]]`` array
    keeps the default classes; a given ``[[classes]]`` array replaces them all, in file order.
    """
    _check_keys(source, 'top level', data, _TOP_KEYS)
    detector = data.get('detector', {})
    if not isinstance(detector, dict):
        raise _fail(source, '[detector]', f'expected a table, got {detector!r}')
    params = _parse_detector(source, detector)
    if 'classes' not in data:
        return HsvConfig(DEFAULT_CLASSES, params)
    items = data['classes']
    if not isinstance(items, list) or not items:
        raise _fail(source, 'classes', 'expected a non-empty array of [[classes]] tables')
    classes = tuple(_parse_class(source, i, item) for i, item in enumerate(items))
    seen: set[str] = set()
    for index, cls in enumerate(classes):
        if cls.name in seen:
            raise _fail(source, f'classes[{index}].name', f'duplicate class name {cls.name!r}')
        seen.add(cls.name)
    return HsvConfig(classes, params)


def load_config(path: str | Path) -> HsvConfig:
    """Read and validate an hsv TOML configuration file."""
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as exc:
        msg = f'{path}: cannot read hsv config: {exc}'
        raise BackendError(msg) from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = f'{path}: not valid TOML: {exc}'
        raise BackendError(msg) from exc
    return parse_config(data, str(path))


def _apply_extra(config: HsvConfig, extra: Mapping[str, str]) -> HsvConfig:
    """Overrides of ``[detector]`` keys given as backend options (strings)."""
    if not extra:
        return config
    table: dict[str, object] = {}
    for key, text in extra.items():
        if key not in _DETECTOR_KEYS:
            msg = f'hsv: unknown option {key!r} (known: {", ".join(sorted(_DETECTOR_KEYS))})'
            raise BackendError(msg)
        try:
            table[key] = float(text) if key == 'min_area' else int(text)
        except ValueError as err:
            msg = f'hsv: option {key}={text!r} is not a number'
            raise BackendError(msg) from err
    current = {key: getattr(config.detector, key) for key in _DETECTOR_KEYS}
    return replace(config, detector=_parse_detector('backend options', current | table))


def _toml_triple(value: Hsv) -> str:
    return f'[{value[0]}, {value[1]}, {value[2]}]'


def config_to_toml(config: HsvConfig, title: str = 'replaybench hsv backend configuration') -> str:
    """The TOML text that ``load_config`` reads back as ``config``."""
    d = config.detector
    lines = [
        f'# {title}.',
        '# HSV on the OpenCV 8-bit scale: H 0..180, S 0..255, V 0..255; bounds are inclusive.',
        '# Classes get class_index 0, 1, ... in file order; a class is the union of its ranges.',
        '',
        '[detector]',
        f'min_area = {d.min_area!r}  # smallest contour area, px²',
        f'kernel = {d.kernel}  # odd elliptic kernel size; 1 disables morphology',
        f'open_iterations = {d.open_iterations}',
        f'close_iterations = {d.close_iterations}',
    ]
    for cls in config.classes:
        ranges = ', '.join(f'[{_toml_triple(lo)}, {_toml_triple(hi)}]' for lo, hi in cls.ranges)
        lines += ['', '[[classes]]', f'name = {json.dumps(cls.name)}', f'ranges = [{ranges}]']
    return '\n'.join(lines) + '\n'


def default_config_toml() -> str:
    """The built-in defaults as TOML (the text of ``docs/hsv-default.toml``)."""
    return config_to_toml(HsvConfig(), 'replaybench hsv backend: the built-in defaults')


def blob_score(pixels: int, box_area: int, mean_saturation: float, saturation_floor: int) -> float:
    """``fill * (0.5 + 0.5 * margin)`` rounded to 6 digits; see the module docstring."""
    fill = min(pixels / box_area, 1.0) if box_area > 0 else 0.0
    if saturation_floor >= 255:
        margin = 1.0
    else:
        margin = (mean_saturation - saturation_floor) / (255 - saturation_floor)
        margin = min(max(margin, 0.0), 1.0)
    return round(fill * (0.5 + 0.5 * margin), 6)


def _sort_key(det: Detection) -> tuple[int, float, float, float, float, float]:
    return (det.class_index, -det.score, det.y0, det.x0, det.y1, det.x1)


class _Buffers:
    """Per-frame-size work images, reused so that no frame pays for fresh page faults."""

    def __init__(self, height: int, width: int, n_hues: int, n_svs: int, n_classes: int) -> None:
        shape = (height, width)
        self.shape = shape
        self.hsv = np.empty((height, width, 3), dtype=np.uint8)
        self.plane = np.empty(shape, dtype=np.uint8)
        self.hues = [np.empty(shape, dtype=np.uint8) for _ in range(n_hues)]
        self.svs = [np.empty(shape, dtype=np.uint8) for _ in range(n_svs)]
        self.masks = [np.empty(shape, dtype=np.uint8) for _ in range(n_classes)]
        self.part = np.empty(shape, dtype=np.uint8)


class ColourMorphology:
    """What the colour backends (``hsv``, ``hsv-seg``) share: OpenCV's availability, the
    elliptic kernel of their configuration's open / close, made when they open, and
    ``cv2.setNumThreads(options.threads)`` while they are open. A subclass sets ``config``,
    ``options``, ``_kernel`` and ``_saved_threads`` (None) and ``_buffers`` in ``__init__``."""

    name: ClassVar[str]
    #: ``detect`` never reads ``frame.camera_info``.
    reads_camera_info: ClassVar[bool] = False
    config: HsvConfig
    options: BackendOptions
    _kernel: npt.NDArray[np.uint8] | None
    _saved_threads: int | None
    _buffers: object | None

    @classmethod
    def available(cls) -> Availability:
        if importlib.util.find_spec('cv2') is None:
            return Availability(ok=False, reason='OpenCV (cv2) is not installed')
        return Availability(ok=True)

    def open(self) -> None:
        try:
            import cv2
        except ImportError as exc:
            msg = f'{self.name}: cannot import OpenCV: {exc}'
            raise BackendUnavailableError(msg) from exc
        params = self.config.detector
        self._kernel = np.asarray(
            cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (params.kernel, params.kernel)),
            dtype=np.uint8,
        )
        if self.options.threads is not None and self._saved_threads is None:
            self._saved_threads = cv2.getNumThreads()
            cv2.setNumThreads(self.options.threads)

    def close(self) -> None:
        self._buffers = None
        if self._saved_threads is not None:
            import cv2

            cv2.setNumThreads(self._saved_threads)
            self._saved_threads = None

    def _colour_source(self, frame: Frame) -> tuple[npt.NDArray[np.uint8], int]:
        """The frame as an HxWx3 uint8 image and the cv2 code that turns it into HSV (rgb8 and
        bgr8 as they are, other encodings through BGR); BackendError for any other shape."""
        import cv2

        image = frame.image
        encoding = frame.encoding
        if encoding == 'rgb8':
            code = cv2.COLOR_RGB2HSV
        elif encoding == 'bgr8':
            code = cv2.COLOR_BGR2HSV
        else:
            image = to_bgr8(image, encoding)
            code = cv2.COLOR_BGR2HSV
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            msg = (
                f'{self.name}: frame {frame.topic}#{frame.seq}: expected HxWx3 uint8 for '
                f'{encoding}, got shape {image.shape} {image.dtype}'
            )
            raise BackendError(msg)
        return cast('npt.NDArray[np.uint8]', image), code


class HsvBackend(ColourMorphology):
    """OpenCV colour-blob detector; classes and thresholds from ``options.config`` (TOML).

    ``options.extra`` may override ``[detector]`` keys (``min_area``, ``kernel``,
    ``open_iterations``, ``close_iterations``). ``options.threads`` sets
    ``cv2.setNumThreads`` while the backend is open.
    """

    name: ClassVar[str] = 'hsv'
    description: ClassVar[str] = 'OpenCV HSV colour blobs: inRange, open/close, contours (CPU)'

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        config = load_config(self.options.config) if self.options.config else HsvConfig()
        self.config = _apply_extra(config, self.options.extra)
        params = self.config.detector
        self._morph = params.kernel > 1 and (params.open_iterations + params.close_iterations) > 0
        radius = params.kernel // 2
        self._pad = radius * (params.open_iterations + params.close_iterations + 1) + 1
        # A class mask is the union over its ranges of (hue interval on the H plane) AND
        # (S/V box on the HSV image): the same pixels as one 3-channel inRange per range, but
        # each distinct hue interval and S/V box is thresholded once per frame.
        self._hues: list[tuple[int, int]] = []
        self._svs: list[tuple[Hsv, Hsv]] = []
        self._plan: list[list[tuple[int, int]]] = []
        for cls in self.config.classes:
            pairs: list[tuple[int, int]] = []
            for lo, hi in cls.ranges:
                hue = (lo[0], hi[0])
                sv = ((0, lo[1], lo[2]), (255, hi[1], hi[2]))
                if hue not in self._hues:
                    self._hues.append(hue)
                if sv not in self._svs:
                    self._svs.append(sv)
                pair = (self._hues.index(hue), self._svs.index(sv))
                if pair not in pairs:
                    pairs.append(pair)
            self._plan.append(pairs)
        self._floors = [cls.saturation_floor for cls in self.config.classes]
        self._kernel: npt.NDArray[np.uint8] | None = None
        self._saved_threads: int | None = None
        self._buffers: _Buffers | None = None

    def info(self) -> dict[str, Any]:
        params = self.config.detector
        facts: dict[str, Any] = {
            'config': str(self.options.config) if self.options.config else None,
            'classes': [
                {
                    'class_index': index,
                    'name': cls.name,
                    'ranges': [[list(lo), list(hi)] for lo, hi in cls.ranges],
                }
                for index, cls in enumerate(self.config.classes)
            ],
            'detector': {key: getattr(params, key) for key in _DETECTOR_KEYS},
            'score': 'fill * (0.5 + 0.5 * saturation_margin)',
            'threads': self.options.threads,
        }
        if self._kernel is not None:
            import cv2

            facts['opencv'] = cv2.__version__
        return facts

    def _buffers_for(self, height: int, width: int) -> _Buffers:
        buffers = self._buffers
        if buffers is None or buffers.shape != (height, width):
            buffers = _Buffers(height, width, len(self._hues), len(self._svs), len(self._plan))
            self._buffers = buffers
        return buffers

    def _hsv(self, frame: Frame) -> npt.NDArray[np.uint8]:
        import cv2

        image, code = self._colour_source(frame)
        buffers = self._buffers_for(image.shape[0], image.shape[1])
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
        plane = cv2.extractChannel(hsv, 0, dst=buffers.plane)
        for (lo, hi), out in zip(self._hues, buffers.hues, strict=True):
            cv2.inRange(plane, lo, hi, dst=out)
        for (lower, upper), out in zip(self._svs, buffers.svs, strict=True):
            cv2.inRange(hsv, lower, upper, dst=out)
        part = buffers.part
        masks: list[tuple[int, int, int, npt.NDArray[np.uint8]]] = []
        for index, pairs in enumerate(self._plan):
            mask = buffers.masks[index]
            hue_index, sv_index = pairs[0]
            cv2.bitwise_and(buffers.hues[hue_index], buffers.svs[sv_index], dst=mask)
            for hue_index, sv_index in pairs[1:]:
                cv2.bitwise_and(buffers.hues[hue_index], buffers.svs[sv_index], dst=part)
                cv2.bitwise_or(mask, part, dst=mask)
            x, y, w, h = cv2.boundingRect(mask)
            if w == 0:
                continue
            # Morphology reaches at most self._pad pixels: working on the mask's bounding box
            # plus that margin gives the same pixels as working on the full frame.
            x0, y0 = max(x - self._pad, 0), max(y - self._pad, 0)
            x1, y1 = min(x + w + self._pad, width), min(y + h + self._pad, height)
            roi = mask[y0:y1, x0:x1]
            if self._morph and params.open_iterations:
                cv2.morphologyEx(
                    roi, cv2.MORPH_OPEN, kernel, dst=roi, iterations=params.open_iterations
                )
            if self._morph and params.close_iterations:
                cv2.morphologyEx(
                    roi, cv2.MORPH_CLOSE, kernel, dst=roi, iterations=params.close_iterations
                )
            masks.append((index, x0, y0, roi))
        t2 = clock()

        detections: list[Detection] = []
        min_area = params.min_area
        for index, ox, oy, roi in masks:
            label = self.config.classes[index].name
            floor = self._floors[index]
            contours, _ = cv2.findContours(roi, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            for contour in contours:
                if cv2.contourArea(contour) < min_area:
                    continue
                bx, by, bw, bh = cv2.boundingRect(contour)
                blob = np.zeros((bh, bw), dtype=np.uint8)
                cv2.drawContours(blob, [contour], -1, 255, cv2.FILLED, offset=(-bx, -by))
                cv2.bitwise_and(blob, roi[by : by + bh, bx : bx + bw], dst=blob)
                pixels = cv2.countNonZero(blob)
                if pixels == 0:
                    continue
                gx, gy = ox + bx, oy + by
                mean_s = cv2.mean(hsv[gy : gy + bh, gx : gx + bw], mask=blob)[1]
                score = blob_score(pixels, bw * bh, mean_s, floor)
                detections.append(
                    Detection(
                        index, label, score, float(gx), float(gy), float(gx + bw), float(gy + bh)
                    )
                )
        detections.sort(key=_sort_key)
        t3 = clock()
        return BackendResult(
            tuple(detections),
            StageTimes(preprocess_ns=t1 - t0, infer_ns=t2 - t1, postprocess_ns=t3 - t2),
        )
