"""The runner's side of recorded outputs: which message types the ``recorded`` backend reads
(``RECORDED_READERS``), which topic it replays, its outputs read by type (the readers of
``replaybench.decode.recorded`` and ``replaybench.fiducials.recorded``), and each frame's
recorded latency (``replaybench.results.recorded_latency``).

``RECORDED_READERS`` maps a message type (ROS 2 spelling) to its ``OutputReader``
(``replaybench.decode.recorded`` says what an entry provides); three types are read:

* ``vision_msgs/msg/Detection2DArray`` (task ``detections``): the boxes;
* ``isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray`` (task ``tags``): a ``TagResult``
  as the ``apriltag`` and ``aruco`` backends return it;
* ``sensor_msgs/msg/Image`` label masks (task ``segmentation``): never picked alone (camera
  topics are Images too), named with ``--recorded-topic``, and left out of the replayed cameras.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple, TypeVar

from replaybench.decode.recorded import (
    OutputReader,
    read_detection2d_array,
    read_label_mask,
    read_recorded_outputs,
)
from replaybench.errors import UsageError
from replaybench.fiducials.recorded import read_tag_array_output
from replaybench.fiducials.types import TagResult
from replaybench.results.recorded_latency import RecordedTimes, recorded_times

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence
    from pathlib import Path

    from replaybench.decode.recorded import RecordedOutput
    from replaybench.sources import Source
    from replaybench.types import TopicInfo

__all__ = [
    'NOT_RECORDED',
    'RECORDED_READERS',
    'RecordedTopic',
    'boxes_scored',
    'frame_recorded_times',
    'output_reader',
    'read_recorded',
    'readable_types',
    'recorded_candidates',
    'recorded_note',
    'without_recorded',
]

_T = TypeVar('_T')

#: The recorded-output columns of a frame of a replayed (timed) backend: all empty.
NOT_RECORDED = RecordedTimes(None, None, None)


#: message type (ROS 2 spelling) -> its reader. Adding a task's recorded output is one entry.
RECORDED_READERS: Mapping[str, OutputReader] = {
    'vision_msgs/msg/Detection2DArray': OutputReader('detections', read_detection2d_array),
    'isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray': OutputReader(
        'tags', read_tag_array_output, missing=TagResult(())
    ),
    'sensor_msgs/msg/Image': OutputReader(
        'segmentation', read_label_mask, candidate=False, outputs='masks'
    ),
}


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


def boxes_scored(reader: OutputReader | None, timed: bool) -> bool:
    """Whether a frame's boxes are scored against box ground truth: not for a backend replaying
    recorded masks (a frame without its mask has no boxes either: it is left unscored, as a
    segmentation backend's frames are)."""
    return timed or reader is None or reader.task != 'segmentation'


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
