"""A tracker over a box backend: the backend ``DETECTOR+TRACKER`` (``hsv+sort``).

Each ``DETECTOR+TRACKER`` is a backend of its own: a new instance of the detector, with the
run's options, feeding one tracker (``replaybench.tracking.trackers``) inside its ``detect``.
Its frames are timed as the detector's are, the tracker's time included (``latency_ms``); the
tracker's own time per frame is the frame's ``track_ms`` (``TrackStage``, the tracks task's
frames.csv column). Each camera topic of each input has a tracker of its own, which gets that
camera's frames the replay gives the backend, in replay order; a frame dropped from the queue is
never given to it. Its results are the tracks the tracker reports, as
detections carrying the track's id (``Detection.id``) and the matched box's class and score.

Tracker parameters: the keys of the tracker's ``__init__`` (``max_age``, ``min_hits``,
``iou_threshold``, ``det_thresh`` of ``sort``; ``track_thresh``, ``low_thresh``,
``match_thresh``, ``track_buffer`` of ``bytetrack``; ``iou_threshold`` of ``iou``), read from
the ``[tracker.NAME]`` table of the ``--config`` file and then from the backend options
(``BackendOptions.extra``: a sweep's ``--param hsv+sort.max_age=...``), which win. The other
options go to the detector.
"""

from __future__ import annotations

import inspect
import time
import tomllib
from dataclasses import dataclass, replace
from itertools import chain, repeat
from operator import itemgetter
from typing import TYPE_CHECKING, Any, ClassVar, cast

from replaybench.backends.base import (
    DEFAULT_TASK,
    Availability,
    Backend,
    BackendOptions,
    backend_task,
    backend_traits,
)
from replaybench.errors import BackendError, UsageError
from replaybench.types import BackendResult, Detection

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.types import Frame

__all__ = [
    'TRACKERS',
    'TRACKS_TASK',
    'TrackStage',
    'split_name',
    'tracked_class',
    'tracker_params',
    'with_trackers',
]

#: the task of a tracked backend's results (``replaybench.tasks.tracks``)
TRACKS_TASK = 'tracks'
#: the trackers ``--tracker`` and ``DETECTOR+TRACKER`` know (``replaybench.tracking.trackers``)
TRACKERS: tuple[str, ...] = ('iou', 'sort', 'bytetrack')


@dataclass(frozen=True, slots=True)
class TrackStage:
    """What a tracked backend adds to a frame's result (``BackendResult.output``): the
    tracker's time on it, in nanoseconds."""

    track_ns: int


def split_name(name: str) -> tuple[str, str] | None:
    """``('hsv', 'sort')`` for ``'hsv+sort'``; None for a name without ``+``.
    ``UsageError`` for an unknown tracker or an empty part."""
    if '+' not in name:
        return None
    detector, _, tracker = name.rpartition('+')
    if not detector or not tracker:
        msg = f'backend {name!r}: use DETECTOR+TRACKER (e.g. hsv+sort)'
        raise UsageError(msg)
    if tracker not in TRACKERS:
        msg = f'backend {name!r}: unknown tracker {tracker!r}; known: {", ".join(TRACKERS)}'
        raise UsageError(msg)
    return detector, tracker


def with_trackers(backends: Sequence[str], trackers: Sequence[str]) -> list[str]:
    """``run --backend B --tracker T``'s backends: each backend, then ``B+T`` for each tracker
    (``UsageError`` for an unknown tracker, one given twice, or an instance ``LABEL=NAME``
    among the backends: labels hold no ``+``)."""
    for tracker in trackers:
        if tracker not in TRACKERS:
            msg = f'--tracker {tracker!r}: unknown tracker; known: {", ".join(TRACKERS)}'
            raise UsageError(msg)
    if len(set(trackers)) != len(trackers):
        msg = '--tracker: a tracker is given twice'
        raise UsageError(msg)
    instances = [b for b in backends if '=' in b]
    if trackers and instances:
        msg = (
            f'--tracker over the instance --backend {instances[0]!r}: give its tracked row as an '
            'instance of its own, --backend LABEL=NAME+TRACKER (docs/tracking.md)'
        )
        raise UsageError(msg)
    return [name for b in backends for name in (b, *(f'{b}+{t}' for t in trackers))]


def _tracker_keys(tracker: str) -> tuple[str, ...]:
    from replaybench.tracking.trackers import ByteTrackTracker, IouTracker, SortTracker

    cls: type[Any] = {'iou': IouTracker, 'sort': SortTracker, 'bytetrack': ByteTrackTracker}[
        tracker
    ]
    return tuple(inspect.signature(cls).parameters)


def _number(name: str, key: str, value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        msg = f'{where}: tracker {name} option {key}={value!r} is not a number'
        raise BackendError(msg)
    try:
        return float(value)
    except ValueError:
        msg = f'{where}: tracker {name} option {key}={value!r} is not a number'
        raise BackendError(msg) from None


def tracker_params(
    tracker: str, options: BackendOptions
) -> tuple[dict[str, float], dict[str, str]]:
    """The tracker's parameters (the config file's ``[tracker.NAME]``, then the backend options
    of its keys) and the backend options left for the detector. ``BackendError`` in one line
    for an unknown key of the table or a value that is no number."""
    keys = _tracker_keys(tracker)
    params: dict[str, float] = {}
    if options.config is not None and options.config.suffix == '.toml':
        try:
            data = tomllib.loads(options.config.read_text(encoding='utf-8'))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
            msg = f'{options.config}: cannot read the tracker options: {err}'
            raise BackendError(msg) from err
        table = data.get('tracker', {})
        own = table.get(tracker, {}) if isinstance(table, dict) else None
        if not isinstance(own, dict):
            msg = f'{options.config}: [tracker.{tracker}] must be a table'
            raise BackendError(msg)
        for key, value in own.items():
            if key not in keys:
                msg = (
                    f'{options.config}: [tracker.{tracker}] has no option {key!r} '
                    f'(known: {", ".join(keys)})'
                )
                raise BackendError(msg)
            params[key] = _number(tracker, key, value, str(options.config))
    rest: dict[str, str] = {}
    for key, text in options.extra.items():
        if key in keys:
            params[key] = _number(tracker, key, text, 'backend options')
        else:
            rest[key] = text
    return params, rest


def _tracked(
    reported: tuple[list[int], list[list[float]], list[int]], columns: Sequence[tuple[Any, ...]]
) -> tuple[Detection, ...]:
    """The tracks a tracker's ``step`` reports as detections: the matched box's class, label
    and score, the track's box and id. ``columns``: the frame's detections as columns (class
    indices, labels, scores, ...); built by ``zip`` and ``map``, no Python per track."""
    ids, boxes, matched = reported
    if not ids:
        return ()
    if min(matched) < 0:  # a prediction without a box of this frame: not reported
        kept = [n for n, d in enumerate(matched) if d >= 0]
        if not kept:
            return ()
        ids = [ids[n] for n in kept]
        boxes = [[column[n] for n in kept] for column in boxes]
        matched = [matched[n] for n in kept]
    heads: tuple[tuple[Any, ...], ...]
    if len(matched) > 1:
        pick = itemgetter(*matched)
        heads = (pick(columns[0]), pick(columns[1]), pick(columns[2]))
    else:
        heads = tuple((column[matched[0]],) for column in columns[:3])
    fields = zip(*heads, *boxes, map(str, ids), strict=True)
    return tuple(map(tuple.__new__, repeat(Detection), fields))


class _TrackedBase:
    """A detector's instance and a tracker: see the module's docstring."""

    detector_class: ClassVar[type[Backend]]
    tracker_name: ClassVar[str]
    name: ClassVar[str]
    description: ClassVar[str]
    task: ClassVar[str] = TRACKS_TASK

    @classmethod
    def available(cls) -> Availability:
        return cls.detector_class.available()

    def __init__(self, options: BackendOptions) -> None:
        self.params, rest = tracker_params(self.tracker_name, options)
        self.detector: Backend = self.detector_class(replace(options, extra=rest))  # type: ignore[call-arg]
        self.tracker: Any = self._new_tracker()  # checks the parameters before any frame
        #: one tracker per camera topic of each input: a camera's tracks are its own
        self._trackers: dict[tuple[int, str], Any] = {}
        self._np: Any = None

    def _new_tracker(self) -> Any:
        from replaybench.tracking.trackers import make_tracker

        try:
            return make_tracker(self.tracker_name, **self.params)
        except ValueError as err:
            msg = f'backend {self.name!r}: {err}'
            raise BackendError(msg) from None

    def prepare(self, recorded: Any) -> None:
        prepare = getattr(self.detector, 'prepare', None)
        if callable(prepare):
            prepare(recorded)

    def task_of(self, input_index: int) -> str:
        """``tracks`` where the detector gives boxes (a recording's tracks among them, whose
        ids it does not keep); ``BackendError`` (exit 2) otherwise."""
        inner = backend_task(self.detector, input_index)
        if inner not in (DEFAULT_TASK, TRACKS_TASK):  # recorded tracks are boxes too
            msg = (
                f'backend {self.name!r}: a tracker needs a box backend; '
                f'{self.detector_class.name} gives {inner} here'
            )
            raise BackendError(msg)
        return TRACKS_TASK

    def open(self) -> None:
        import numpy as np

        from replaybench.tracking.metrics import _assign

        self._np = np
        _assign(np.zeros((1, 1)))  # the solver imported here, never inside a timed frame
        self.detector.open()

    def detect(self, frame: Frame) -> BackendResult:
        found = self.detector.detect(frame)
        np = self._np
        t0 = time.perf_counter_ns()
        # the detections as columns (class, label, score, x0, y0, x1, y1, id): one zip; the
        # scores and boxes as rows of one array
        columns = list(zip(*found.detections, strict=True))
        n = len(found.detections)
        values = np.fromiter(chain.from_iterable(columns[2:7]), np.float64, 5 * n).reshape(5, n)
        stream = (frame.input_index, frame.topic)
        tracker = self._trackers.get(stream)
        if tracker is None:
            tracker = self._trackers[stream] = self._new_tracker()
        out = _tracked(tracker.step(values[1:].T, values[0]), columns)
        took = time.perf_counter_ns() - t0
        return BackendResult(out, found.stages, output=TrackStage(took))

    def forget_warmup(self) -> None:
        forget = getattr(self.detector, 'forget_warmup', None)
        if callable(forget):
            forget()

    def info(self) -> dict[str, Any]:
        return {
            'detector': self.detector_class.name,
            'detector_info': self.detector.info(),
            'tracker': self.tracker_name,
            'tracker_params': dict(sorted(self.params.items())),
        }

    def close(self) -> None:
        self.detector.close()


def tracked_class(name: str, detector_class: type[Backend], tracker: str) -> type[Backend]:
    """The backend class ``name`` (``DETECTOR+TRACKER``): ``tracker`` over ``detector_class``.
    ``UsageError`` (exit 2) for a detector that declares another task than boxes or takes
    frame sets."""
    traits = backend_traits(detector_class)
    if traits.task != DEFAULT_TASK or traits.takes_frame_sets:
        what = 'stereo pairs' if traits.takes_frame_sets else traits.task
        msg = f'backend {name!r}: a tracker needs a box backend; {detector_class.name} gives {what}'
        raise UsageError(msg)
    attrs: Mapping[str, Any] = {
        'detector_class': detector_class,
        'tracker_name': tracker,
        'name': name,
        'description': f'{detector_class.description} tracked by {tracker}',
        'device': traits.device,
        'measures_latency': traits.measures_latency,
        'uses_recorded_detections': traits.uses_recorded_detections,
        'reads_camera_info': traits.reads_camera_info,
    }
    return cast('type[Backend]', type(f'Tracked_{tracker}', (_TrackedBase,), dict(attrs)))
