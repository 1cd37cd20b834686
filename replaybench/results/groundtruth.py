"""Ground truth from an annotation file beside the bag: COCO JSON or CVAT XML.

Frames of the bag are matched to annotated images either by stamp (the image's header stamp)
or by seq (the 0-based index of the image message within its topic, ``RawMessage.seq``):

- COCO (``images[]``, ``annotations[]`` with ``bbox`` ``[x, y, w, h]``, ``categories[]``):
  stamp from an image's ``stamp_ns`` (integer nanoseconds), else ``timestamp`` (seconds), else
  the number in ``file_name`` (``frame_1700000000033333333.png`` = nanoseconds,
  ``1700000000.033333333.png`` = seconds); seq from the image's ``seq``, else its ``id``.
  An image may name its ``topic``; it then only matches frames of that topic.
- CVAT for images 1.1 (``<image id name><box label xtl ytl xbr ybr/></image>``): stamp from
  the number in ``name`` as above; seq = ``id``.
- CVAT for video 1.1 (``<track label><box frame xtl ... outside/></track>``): seq = ``frame``
  only; every frame of the task (``<meta>`` size, else up to the last box) is annotated.

Every listed image (every frame of a video task) is an annotated frame, also without boxes:
``lookup`` returns ``()`` for it, and ``None`` for a frame the file does not cover.
"""

from __future__ import annotations

import bisect
import json
import math
import re
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any, Literal

from replaybench.errors import SourceError, UsageError
from replaybench.types import Detection

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping
    from xml.etree.ElementTree import Element

__all__ = [
    'DEFAULT_TOLERANCE_NS',
    'MOT_DISTRACTORS',
    'MOT_PEDESTRIAN',
    'ExternalGroundTruth',
    'GroundTruthFormat',
    'MatchMode',
    'load_ground_truth_file',
    'mot_boxes',
    'stamp_from_name',
]

GroundTruthFormat = Literal['coco', 'cvat-images', 'cvat-video', 'mot']
MatchMode = Literal['stamp', 'seq']

#: Largest difference between a frame's stamp and an annotated stamp that still matches.
DEFAULT_TOLERANCE_NS = 1_000_000
_NS = 1_000_000_000
_SECONDS_NAME = re.compile(r'(\d+)\.(\d+)$')
_LAST_NUMBER = re.compile(r'(\d+)(?!.*\d)')
_Key = tuple[str | None, int]


def stamp_from_name(name: str) -> int | None:
    """The stamp in nanoseconds that a file name carries, or None.

    The name's extension is ignored. ``<sec>.<fraction>`` at the end of the rest is seconds
    (``1700000000.033333333.png``); otherwise the last run of digits is nanoseconds
    (``frame_1700000000033333333.png``).

    >>> stamp_from_name('cam/frame_1700000000033333333.png')
    1700000000033333333
    >>> stamp_from_name('1700000000.5.jpg')
    1700000000500000000
    """
    stem = PurePath(name).name
    if '.' in stem:
        stem = stem.rsplit('.', 1)[0]
    if match := _SECONDS_NAME.search(stem):
        seconds, fraction = match.groups()
        return int(seconds) * _NS + int(fraction[:9].ljust(9, '0'))
    if match := _LAST_NUMBER.search(stem):
        return int(match.group(1))
    return None


@dataclass(frozen=True, slots=True, eq=False)
class ExternalGroundTruth:
    """Annotated frames of a ground-truth file, keyed by (topic or None, stamp_ns or seq).

    ``topic`` restricts every annotated frame to one image topic. ``tolerance_ns`` is how far
    a frame's stamp may be from an annotated stamp (``match == 'stamp'``; the nearest wins).
    ``warnings`` lists what was left out of the file (crowd regions, empty boxes, shapes that
    are not boxes).
    """

    path: Path
    format: GroundTruthFormat
    match: MatchMode
    frames: Mapping[_Key, tuple[Detection, ...]]
    topic: str | None = None
    tolerance_ns: int = DEFAULT_TOLERANCE_NS
    warnings: tuple[str, ...] = ()
    #: a MOTChallenge file's boxes that are not scored (``mot_boxes``): the ones of other
    #: classes and those marked not to consider, each with its class number as ``label``; a
    #: tracker's box matched to a distractor's is not scored either (``MOT_DISTRACTORS``)
    others: Mapping[_Key, tuple[Detection, ...]] = field(default_factory=dict)
    _sorted: dict[str | None, list[int]] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        by_topic: dict[str | None, list[int]] = {}
        for topic, key in self.frames:
            by_topic.setdefault(topic, []).append(key)
        object.__setattr__(self, '_sorted', {t: sorted(keys) for t, keys in by_topic.items()})

    def __len__(self) -> int:
        """The number of annotated frames."""
        return len(self.frames)

    @property
    def topics(self) -> frozenset[str]:
        """The image topics that images of the file name (COCO ``topic``); empty when none do."""
        return frozenset(t for t, _ in self.frames if t is not None)

    @property
    def labels(self) -> list[str]:
        """Every class label in the file's boxes, sorted."""
        return sorted({d.label for dets in self.frames.values() for d in dets})

    def with_topic(self, topic: str | None) -> ExternalGroundTruth:
        """The same annotations, restricted to ``topic`` (None: any topic)."""
        return ExternalGroundTruth(
            self.path,
            self.format,
            self.match,
            self.frames,
            topic,
            self.tolerance_ns,
            self.warnings,
            self.others,
        )

    def others_of(self, topic: str, seq: int) -> tuple[Detection, ...]:
        """A MOTChallenge file's unscored boxes of one frame (``others``)."""
        if self.topic is not None and topic != self.topic:
            return ()
        return self.others.get((topic, seq)) or self.others.get((None, seq)) or ()

    def lookup(self, topic: str, seq: int, stamp_ns: int) -> tuple[Detection, ...] | None:
        """The ground truth of one frame; None when the file does not annotate it."""
        if self.topic is not None and topic != self.topic:
            return None
        key = seq if self.match == 'seq' else stamp_ns
        for scope in (topic, None):
            found = self.frames.get((scope, key))
            if found is not None:
                return found
        if self.match != 'stamp' or self.tolerance_ns <= 0:
            return None
        best: tuple[int, _Key] | None = None
        for scope in (topic, None):
            keys = self._sorted.get(scope)
            if not keys:
                continue
            i = bisect.bisect_left(keys, key)
            for near in keys[max(i - 1, 0) : i + 1]:
                distance = abs(near - key)
                if distance <= self.tolerance_ns and (best is None or distance < best[0]):
                    best = (distance, (scope, near))
        return None if best is None else self.frames[best[1]]


def load_ground_truth_file(
    path: str | Path,
    *,
    match: MatchMode,
    topic: str | None = None,
    tolerance_ns: int = DEFAULT_TOLERANCE_NS,
    seq_offset: int = 0,
) -> ExternalGroundTruth:
    """Read a COCO JSON, CVAT XML or MOTChallenge ``gt.txt`` ground-truth file (the format is
    told by its content; a MOT file is read by ``mot_boxes`` and always matched by seq).

    ``match``: ``'stamp'`` or ``'seq'``. ``topic``: only frames of this image topic are
    annotated. ``seq_offset`` is subtracted from image ids and frame numbers in ``'seq'`` mode
    (1 for COCO files whose image ids start at 1). Raises ``UsageError`` for a missing file or a
    mode the file cannot serve, ``SourceError`` naming the file and the fault for a malformed one.
    """
    path = Path(path)
    if match not in ('stamp', 'seq'):
        msg = f'unknown ground-truth match {match!r}: use stamp or seq'
        raise UsageError(msg)
    if tolerance_ns < 0:
        msg = f'ground-truth stamp tolerance must not be negative, not {tolerance_ns}'
        raise UsageError(msg)
    try:
        data = path.read_bytes()
    except FileNotFoundError as err:
        msg = f'{path}: no such ground-truth file'
        raise UsageError(msg) from err
    except OSError as err:
        msg = f'{path}: cannot read the ground-truth file: {err.strerror or err}'
        raise UsageError(msg) from err
    start = data.lstrip()[:1]
    if data.startswith(b'\xef\xbb\xbf'):
        start = data[3:].lstrip()[:1]
    parser = _Parser(path, match, seq_offset)
    if start in (b'{', b'['):
        fmt, frames = parser.coco(data)
    elif start == b'<':
        fmt, frames = parser.cvat(data)
    elif start[:1].isdigit():
        kept, others = mot_boxes(path)
        return ExternalGroundTruth(
            path, 'mot', 'seq', kept, topic, tolerance_ns, tuple(parser.warnings()), others
        )
    else:
        msg = f'{path}: not a ground-truth file: expected COCO JSON, CVAT XML or MOT gt.txt'
        raise SourceError(msg)
    return ExternalGroundTruth(
        path, fmt, match, frames, topic, tolerance_ns, tuple(parser.warnings())
    )


#: MOT17's pedestrian class (-1: a MOT15 file without classes), the one scored
MOT_PEDESTRIAN = frozenset({1, -1})
#: MOT17's distractor classes (person on vehicle, static person, distractor, reflection): a
#: tracker's box matched to one is not scored, as TrackEval's MOT17 preset removes it
MOT_DISTRACTORS = frozenset({'2', '7', '8', '12'})


def mot_boxes(
    path: Path,
) -> tuple[dict[_Key, tuple[Detection, ...]], dict[_Key, tuple[Detection, ...]]]:
    """A MOTChallenge ground-truth file's boxes by (None, seq), seq its frame number less 1
    (frames count the topic's images from 1), as TrackEval's MOT17 preset reads them: scored,
    the pedestrians (class 1, or -1) not marked ``consider`` 0, labelled ``pedestrian`` with
    their id; the others (``ExternalGroundTruth.others``) with their class number as label.
    ``UsageError`` naming the line for a malformed one."""
    from replaybench.tracking.motfile import read_mot_file

    kept: dict[_Key, list[Detection]] = {}
    others: dict[_Key, list[Detection]] = {}
    for box in read_mot_file(path):
        key: _Key = (None, box.frame - 1)
        scored = box.cls in MOT_PEDESTRIAN and box.conf != 0
        det = Detection(
            0 if scored else -1,
            'pedestrian' if scored else str(box.cls),
            1.0,
            box.x,
            box.y,
            box.x + box.w,
            box.y + box.h,
            str(box.id),
        )
        (kept if scored else others).setdefault(key, []).append(det)
    last = max((seq for _, seq in (*kept, *others)), default=-1)
    # every frame up to the file's last is annotated: a frame without a line has no object
    frames: dict[_Key, tuple[Detection, ...]] = {
        (None, seq): tuple(kept.get((None, seq), ())) for seq in range(last + 1)
    }
    return frames, {k: tuple(v) for k, v in others.items()}


class _Parser:
    """Reads one file; collects what it leaves out."""

    def __init__(self, path: Path, match: MatchMode, seq_offset: int) -> None:
        self.path = path
        self.match = match
        self.seq_offset = seq_offset
        self.left_out: dict[str, int] = {}
        self.frames: dict[_Key, tuple[Detection, ...]] = {}
        self.names: dict[_Key, str] = {}

    def fail(self, what: str) -> SourceError:
        return SourceError(f'{self.path}: {what}')

    def skip(self, reason: str) -> None:
        self.left_out[reason] = self.left_out.get(reason, 0) + 1

    def warnings(self) -> list[str]:
        return [f'{self.path}: left out {n} {reason}' for reason, n in self.left_out.items()]

    def add_frame(self, key: _Key, where: str, detections: Iterable[Detection]) -> None:
        if key in self.names:
            scope = f' on {key[0]}' if key[0] is not None else ''
            what = 'seq' if self.match == 'seq' else 'stamp'
            msg = f'{where} and {self.names[key]} both have {what} {key[1]}{scope}'
            raise self.fail(msg)
        self.names[key] = where
        self.frames[key] = tuple(detections)

    def seq(self, value: int) -> int:
        return value - self.seq_offset

    # ----------------------------------------------------------------------------- COCO

    def coco(self, data: bytes) -> tuple[GroundTruthFormat, dict[_Key, tuple[Detection, ...]]]:
        try:
            doc = json.loads(data, parse_float=Decimal)
        except json.JSONDecodeError as err:
            msg = f'invalid JSON (line {err.lineno}, column {err.colno}): {err.msg}'
            raise self.fail(msg) from err
        except UnicodeDecodeError as err:
            msg = f'invalid JSON: not UTF-8 text ({err.reason} at byte {err.start})'
            raise self.fail(msg) from err
        if not isinstance(doc, dict):
            msg = 'not a COCO file: the top level must be an object with "images", "annotations"'
            msg += ' and "categories"'
            raise self.fail(msg)
        images = self._list(doc, 'images')
        annotations = self._list(doc, 'annotations')
        categories = self._list(doc, 'categories')
        names: dict[int, str] = {}
        for i, cat in enumerate(categories):
            where = f'categories[{i}]'
            cat = self._object(cat, where)
            cid = self._int(cat.get('id'), f'{where}.id')
            name = cat.get('name')
            if not isinstance(name, str) or not name:
                msg = f'{where}.name must be a non-empty string'
                raise self.fail(msg)
            if cid in names:
                msg = f'{where}: category id {cid} appears twice'
                raise self.fail(msg)
            names[cid] = name
        keys: dict[int, _Key] = {}
        wheres: dict[int, str] = {}
        for i, image in enumerate(images):
            image = self._object(image, f'images[{i}]')
            image_id = self._int(image.get('id'), f'images[{i}].id')
            file_name = image.get('file_name')
            where = f'images[{i}]' + (f' ({file_name})' if isinstance(file_name, str) else '')
            if image_id in keys:
                msg = f'{where}: image id {image_id} appears twice'
                raise self.fail(msg)
            scope = image.get('topic')
            if scope is not None and not isinstance(scope, str):
                msg = f'{where}.topic must be a string'
                raise self.fail(msg)
            keys[image_id] = (scope or None, self._coco_key(image, image_id, where))
            wheres[image_id] = where
        boxes: dict[int, list[Detection]] = {image_id: [] for image_id in keys}
        for i, ann in enumerate(annotations):
            where = f'annotations[{i}]'
            ann = self._object(ann, where)
            image_id = self._int(ann.get('image_id'), f'{where}.image_id')
            if image_id not in boxes:
                msg = f'{where}: image_id {image_id} is not in images'
                raise self.fail(msg)
            cid = self._int(ann.get('category_id'), f'{where}.category_id')
            if cid not in names:
                msg = f'{where}: category_id {cid} is not in categories'
                raise self.fail(msg)
            bbox = ann.get('bbox')
            if not isinstance(bbox, list) or len(bbox) != 4:
                msg = f'{where}.bbox must be [x, y, width, height]'
                raise self.fail(msg)
            x, y, w, h = (self._float(v, f'{where}.bbox') for v in bbox)
            if ann.get('iscrowd') in (1, True):
                self.skip('crowd regions (iscrowd 1)')
                continue
            if w <= 0 or h <= 0:
                self.skip('boxes without area')
                continue
            boxes[image_id].append(Detection(cid, names[cid], 1.0, x, y, x + w, y + h))
        for image_id, key in keys.items():
            self.add_frame(key, wheres[image_id], boxes[image_id])
        return 'coco', self.frames

    def _coco_key(self, image: Mapping[str, Any], image_id: int, where: str) -> int:
        if self.match == 'seq':
            if 'seq' in image:
                return self.seq(self._int(image['seq'], f'{where}.seq'))
            return self.seq(image_id)
        if image.get('stamp_ns') is not None:
            value = image['stamp_ns']
            if isinstance(value, str) and value.strip().isdigit():
                return int(value)
            return self._int(value, f'{where}.stamp_ns')
        if image.get('timestamp') is not None:
            return self._seconds(image['timestamp'], f'{where}.timestamp')
        name = image.get('file_name')
        stamp = stamp_from_name(name) if isinstance(name, str) else None
        if stamp is None:
            msg = (
                f'{where} has no stamp: give it stamp_ns or timestamp, put the stamp in '
                'file_name (frame_<nanoseconds>.png), or match by seq'
            )
            raise self.fail(msg)
        return stamp

    def _list(self, doc: Mapping[str, Any], key: str) -> list[Any]:
        value = doc.get(key)
        if not isinstance(value, list):
            missing = 'is missing' if value is None else 'must be a list'
            msg = f'not a COCO file: "{key}" {missing}'
            raise self.fail(msg)
        return value

    def _object(self, value: Any, where: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            msg = f'{where} must be an object'
            raise self.fail(msg)
        return value

    def _int(self, value: Any, where: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, Decimal) and value == value.to_integral_value():
                return int(value)
            msg = f'{where} must be an integer, not {value!r}'
            raise self.fail(msg)
        return value

    def _float(self, value: Any, where: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float | Decimal):
            msg = f'{where} must hold numbers, not {value!r}'
            raise self.fail(msg)
        number = float(value)
        if not math.isfinite(number):
            msg = f'{where} must hold finite numbers'
            raise self.fail(msg)
        return number

    def _seconds(self, value: Any, where: str) -> int:
        try:
            if isinstance(value, bool) or not isinstance(value, int | Decimal | str):
                raise InvalidOperation
            seconds = Decimal(value)
            if not seconds.is_finite():
                raise InvalidOperation
        except (InvalidOperation, ValueError) as err:
            msg = f'{where} must be a number of seconds, not {value!r}'
            raise self.fail(msg) from err
        return int((seconds * _NS).to_integral_value())

    # ----------------------------------------------------------------------------- CVAT

    def cvat(self, data: bytes) -> tuple[GroundTruthFormat, dict[_Key, tuple[Detection, ...]]]:
        from xml.etree import ElementTree as ET

        try:
            root = ET.fromstring(data)  # expat refuses entity-expansion bombs
        except ET.ParseError as err:
            line, column = err.position
            msg = f'invalid XML (line {line}, column {column + 1}): {err}'
            raise self.fail(msg) from err
        if root.tag != 'annotations':
            msg = f'not a CVAT file: the root element is <{root.tag}>, not <annotations>'
            raise self.fail(msg)
        images = root.findall('image')
        tracks = root.findall('track')
        if images and tracks:
            msg = 'has both <image> and <track> elements: export as CVAT for images or for video'
            raise self.fail(msg)
        if tracks or (not images and root.find('meta') is not None and _task_size(root)):
            if self.match == 'stamp':
                msg = f'{self.path}: CVAT for video has no image names or stamps: match by seq'
                raise UsageError(msg)
            return 'cvat-video', self._cvat_video(root, tracks)
        for i, image in enumerate(images):
            name = image.get('name')
            where = f'<image> #{i}' + (f' ({name})' if name else '')
            if self.match == 'seq':
                key = self.seq(self._xml_int(image, 'id', where))
            else:
                stamp = stamp_from_name(name) if name else None
                if stamp is None:
                    msg = (
                        f'{where} has no stamp in its name: name images '
                        'frame_<nanoseconds>.png, or match by seq'
                    )
                    raise self.fail(msg)
                key = stamp
            dets: list[Detection] = []
            for child in image:
                if child.tag == 'box':
                    det = self._cvat_box(child, where)
                    if det is not None:
                        dets.append(det)
                elif child.tag in ('polygon', 'polyline', 'points', 'mask', 'ellipse', 'cuboid'):
                    self.skip(f'{child.tag} shapes (only boxes are read)')
            self.add_frame((None, key), where, dets)
        return 'cvat-images', self.frames

    def _cvat_video(
        self, root: Element, tracks: list[Element]
    ) -> dict[_Key, tuple[Detection, ...]]:
        per_frame: dict[int, list[Detection]] = {}
        last = -1
        for t, track in enumerate(tracks):
            label = track.get('label')
            where = f'<track> #{t}'
            if not label:
                msg = f'{where} has no label'
                raise self.fail(msg)
            for child in track:
                if child.tag != 'box':
                    if child.tag in ('polygon', 'polyline', 'points', 'mask', 'ellipse'):
                        self.skip(f'{child.tag} shapes (only boxes are read)')
                    continue
                frame = self._xml_int(child, 'frame', f'{where} <box>')
                last = max(last, frame)
                if child.get('outside') == '1':
                    continue
                det = self._cvat_box(child, f'{where} frame {frame}', label)
                if det is not None:
                    per_frame.setdefault(frame, []).append(det)
        size = _task_size(root)
        count = size if size else last + 1
        beyond = sorted(f for f in per_frame if f >= count or f < 0)
        if beyond:
            msg = f"a box on frame {beyond[-1]}, outside the task's frames 0..{count - 1}"
            raise self.fail(msg)
        for frame in range(count):
            self.add_frame((None, self.seq(frame)), f'frame {frame}', per_frame.get(frame, ()))
        return self.frames

    def _cvat_box(self, box: Element, where: str, label: str | None = None) -> Detection | None:
        label = label or box.get('label')
        if not label:
            msg = f'{where}: <box> has no label'
            raise self.fail(msg)
        x0, y0, x1, y1 = (self._xml_float(box, a, where) for a in ('xtl', 'ytl', 'xbr', 'ybr'))
        rotation = self._xml_float(box, 'rotation', where) if box.get('rotation') else 0.0
        if rotation % 360:
            x0, y0, x1, y1 = _rotated_bounds(x0, y0, x1, y1, rotation)
        if x1 <= x0 or y1 <= y0:
            self.skip('boxes without area')
            return None
        return Detection(-1, label, 1.0, x0, y0, x1, y1)

    def _xml_int(self, element: Element, name: str, where: str) -> int:
        value = element.get(name)
        try:
            return int(value or '')
        except ValueError as err:
            msg = f'{where}: attribute {name}={value!r} must be an integer'
            raise self.fail(msg) from err

    def _xml_float(self, element: Element, name: str, where: str) -> float:
        value = element.get(name)
        try:
            number = float(value or '')
        except ValueError:
            number = math.nan
        if not math.isfinite(number):
            msg = f'{where}: attribute {name}={value!r} must be a number'
            raise self.fail(msg)
        return number


def _task_size(root: Element) -> int:
    """Frames in the task or job of a CVAT export's <meta>; 0 when it does not say."""
    for element in (root.find('meta/task'), root.find('meta/job')):
        if element is None:
            continue
        size = (element.findtext('size') or '').strip()
        if size.isdigit():
            return int(size)
    return 0


def _rotated_bounds(
    x0: float, y0: float, x1: float, y1: float, degrees: float
) -> tuple[float, float, float, float]:
    """The axis-aligned bounds of a box rotated clockwise by ``degrees`` about its centre."""
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    angle = math.radians(degrees)
    cos, sin = math.cos(angle), math.sin(angle)
    xs, ys = [], []
    for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1)):
        dx, dy = x - cx, y - cy
        xs.append(cx + dx * cos - dy * sin)
        ys.append(cy + dx * sin + dy * cos)
    return min(xs), min(ys), max(xs), max(ys)
