"""The runner's side of recorded outputs: which message types the ``recorded`` backend reads
(``RECORDED_READERS``), which topic it replays, its outputs read by type, and each frame's
recorded latency (``replaybench.results.recorded_latency``).

``RECORDED_READERS`` maps a message type (ROS 2 spelling) to its ``OutputReader``
(``replaybench.decode.recorded`` says what an entry provides), gathered from the registered
tasks' ``recorded_readers`` (``replaybench/tasks/<task>/recorded.py``) when first read, so that
a run without the ``recorded`` backend imports none of them. The built-in tasks read three:

* ``vision_msgs/msg/Detection2DArray`` (task ``detections``): the boxes;
* ``isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray`` (task ``tags``): a ``TagResult``
  as the ``apriltag`` and ``aruco`` backends return it;
* ``sensor_msgs/msg/Image`` label masks (task ``segmentation``): never picked alone (camera
  topics are Images too), named with ``--recorded-topic``, and left out of the replayed cameras.
"""

from __future__ import annotations

from collections.abc import MutableMapping
from typing import TYPE_CHECKING, NamedTuple, TypeVar

from replaybench.decode.recorded import OutputReader, read_recorded_outputs
from replaybench.errors import TaskUnavailableError, UsageError
from replaybench.results.recorded_latency import RecordedTimes, recorded_times

if TYPE_CHECKING:
    from collections.abc import Collection, Iterator, Mapping, Sequence
    from pathlib import Path

    from replaybench.decode.recorded import RecordedOutput
    from replaybench.sources import Source
    from replaybench.types import TopicInfo

__all__ = [
    'NOT_RECORDED',
    'RECORDED_READERS',
    'RecordedTopic',
    'frame_recorded_times',
    'output_reader',
    'read_recorded',
    'readable_types',
    'recorded_candidates',
    'recorded_note',
    'task_readers',
    'without_recorded',
]

_T = TypeVar('_T')

#: The recorded-output columns of a frame of a replayed (timed) backend: all empty.
NOT_RECORDED = RecordedTimes(None, None, None)


def task_readers() -> dict[str, OutputReader]:
    """Every registered task's recorded readers, by message type, in the registry's order;
    ``TaskUnavailableError`` when two tasks declare the same message type or an entry is not
    an ``OutputReader``."""
    from replaybench.tasks import get_task, task_names

    readers: dict[str, OutputReader] = {}
    owners: dict[str, str] = {}
    for name in task_names():
        for msgtype, reader in get_task(name).recorded_readers.items():
            if msgtype in owners:
                msg = (
                    f'task {name!r}: recorded message type {msgtype} is read by task '
                    f'{owners[msgtype]!r} already'
                )
                raise TaskUnavailableError(msg)
            if not isinstance(reader, OutputReader):
                msg = f'task {name!r}: the recorded reader of {msgtype} is not an OutputReader'
                raise TaskUnavailableError(msg)
            readers[msgtype] = reader
            owners[msgtype] = name
    return readers


class _RecordedReaders(MutableMapping[str, OutputReader]):
    """``RECORDED_READERS``: the tasks' readers (``task_readers``), gathered when first read."""

    def __init__(self) -> None:
        self._table: dict[str, OutputReader] | None = None

    def _readers(self) -> dict[str, OutputReader]:
        if self._table is None:
            self._table = task_readers()
        return self._table

    def __getitem__(self, msgtype: str) -> OutputReader:
        return self._readers()[msgtype]

    def __setitem__(self, msgtype: str, reader: OutputReader) -> None:
        self._readers()[msgtype] = reader

    def __delitem__(self, msgtype: str) -> None:
        del self._readers()[msgtype]

    def __iter__(self) -> Iterator[str]:
        return iter(self._readers())

    def __len__(self) -> int:
        return len(self._readers())


#: message type (ROS 2 spelling) -> its reader, from the registered tasks' ``recorded_readers``
#: (read on first use). A task's recorded output is one entry of its ``recorded_readers``.
RECORDED_READERS: MutableMapping[str, OutputReader] = _RecordedReaders()


def readable_types() -> str:
    """The message types read, with their outputs, for errors: ``T (detections), ...``; a type
    that is never picked alone says it is named with --recorded-topic."""
    return ', '.join(
        f'{msgtype} ({reader.noun}{"" if reader.candidate else ", named with --recorded-topic"})'
        for msgtype, reader in RECORDED_READERS.items()
    )


def _ros2_name(msgtype: str) -> str:
    package, _, name = msgtype.partition('/')
    return msgtype if '/msg/' in msgtype or not name else f'{package}/msg/{name}'


def output_reader(msgtype: str) -> OutputReader | None:
    """The reader of recorded outputs of ``msgtype`` (ROS 1 or ROS 2 spelling); None if none."""
    return RECORDED_READERS.get(_ros2_name(msgtype))


def recorded_candidates(topics: Mapping[str, str], exclude: Collection[str | None]) -> list[str]:
    """The topics (name -> msgtype) that may be picked without ``--recorded-topic``: of a
    ``candidate`` type, not in ``exclude`` (the ground-truth topics)."""
    return [
        name
        for name, msgtype in topics.items()
        if name not in exclude
        and (reader := output_reader(msgtype)) is not None
        and reader.candidate
    ]


class RecordedTopic(NamedTuple):
    """The recorded output topic of an input: its name, its reader, its outputs keyed by
    (frame_id, stamp_ns)."""

    topic: str
    reader: OutputReader
    outputs: dict[tuple[str, int], RecordedOutput]


def read_recorded(
    path: Path,
    source: Source,
    topics: Sequence[TopicInfo],
    wanted: str | None,
    ground_truth_topics: Collection[str | None],
    notes: list[str],
) -> RecordedTopic:
    """The topic the ``recorded`` backend replays (``wanted``, i.e. --recorded-topic, or the
    only candidate besides the ``ground_truth_topics``), read by its type.

    ``UsageError`` when the topic is not in the file, is of a type without a reader, cannot
    be picked alone, or is an Image topic that does not hold label masks."""
    types = {t.name: t.msgtype for t in topics}
    if wanted is not None:
        if wanted not in types:
            msg = f'{path}: --recorded-topic {wanted} is not in this file'
            raise UsageError(msg)
        if output_reader(types[wanted]) is None:
            msg = (
                f'{path}: --recorded-topic {wanted} is a {types[wanted]} topic; the recorded '
                f'backend reads {readable_types()}'
            )
            raise UsageError(msg)
        topic = wanted
    else:
        candidates = recorded_candidates(types, ground_truth_topics)
        if len(candidates) != 1:
            found = ', '.join(candidates) if candidates else 'none'
            msg = (
                f'{path}: the recorded backend needs --recorded-topic TOPIC (topics it can pick '
                f'alone besides the ground truth: {found}; it reads {readable_types()})'
            )
            raise UsageError(msg)
        topic = candidates[0]
    reader = output_reader(types[topic])
    assert reader is not None  # checked above, or a candidate
    try:
        outputs = read_recorded_outputs(source, topic, reader, notes)
    except UsageError as err:  # an Image topic that holds no label masks
        msg = f'{path}: --recorded-topic {err}'
        raise UsageError(msg) from err
    return RecordedTopic(topic, reader, outputs)


def without_recorded(path: Path, topics: list[_T], recorded_topic: str) -> list[_T]:
    """The camera topics to replay without the recorded output topic (a label-mask Image topic
    is probed as a camera too); ``UsageError`` when no other is left."""
    kept = [t for t in topics if getattr(t, 'name', None) != recorded_topic]
    if not kept:
        msg = (
            f'{path}: {recorded_topic} is the recorded output topic, not a camera: no image '
            'topic is left to replay'
        )
        raise UsageError(msg)
    return kept


def frame_recorded_times(
    outputs: Mapping[tuple[str, int], RecordedOutput],
    frame_id: str,
    stamp_ns: int,
    log_time_ns: int,
) -> RecordedTimes:
    """The recorded output matched to a frame (by frame_id and stamp, as the ``recorded``
    backend matches it) and its latencies against the frame's image."""
    found = outputs.get((frame_id, stamp_ns))
    return recorded_times(log_time_ns, stamp_ns, None if found is None else found.log_time_ns)


def recorded_note(times: RecordedTimes, reader: OutputReader | None = None) -> str:
    """frames.csv's note of a frame of a backend that replays recorded outputs (of
    ``reader``'s type: ``recorded tags: ...``; detections without one)."""
    base = f'recorded {reader.noun if reader is not None else "detections"}: latency not measured'
    extra = times.note
    return f'{base}; {extra}' if extra else base
