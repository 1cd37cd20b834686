"""Perception outputs recorded in a bag (what the robot's own nodes published), read per type.

The ``recorded`` backend replays a recorded output topic as if a backend had produced it. Which
message types it reads, and how, is one table: ``RECORDED_READERS`` maps a message type (ROS 2
spelling, ``vision_msgs/msg/Detection2DArray``) to an ``OutputReader``. An entry provides:

* ``task``: the task type the output belongs to (``'detections'``), named in notes and errors;
* ``read(raw) -> RecordedMessage``: the message's header (frame_id, stamp) and the task's result
  for it, as the ``BackendResult`` a replayed backend of that task would return for the frame
  (``left_out``: values dropped as unusable, e.g. non-finite boxes); raises ``DecodeError`` for a
  message it cannot read (the message is skipped);
* ``candidate``: True when a topic of this type is picked without ``--recorded-topic`` if it is
  the only such topic besides the ground truth (False for types also used for other data, such
  as ``sensor_msgs/msg/Image``, which camera topics use too).

``read_recorded_outputs`` reads a topic through its entry into a table keyed by (frame_id,
stamp_ns), keeping each output's log time: the time the recorder logged it, from which
``replaybench.results.recorded_latency`` derives the recorded latency.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from replaybench.decode.detections import decode_detections
from replaybench.errors import DecodeError
from replaybench.types import BackendResult

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from replaybench.decode.kinds import MessageSource
    from replaybench.types import RawMessage

__all__ = [
    'RECORDED_READERS',
    'OutputReader',
    'RecordedMessage',
    'RecordedOutput',
    'output_reader',
    'read_recorded_outputs',
    'recorded_candidates',
]


@dataclass(frozen=True, slots=True)
class RecordedMessage:
    """One recorded output message, read: its header and the task's result for its image."""

    frame_id: str
    stamp_ns: int
    result: BackendResult
    #: values of the message left out as unusable (non-finite boxes or scores)
    left_out: int = 0


@dataclass(frozen=True, slots=True)
class RecordedOutput:
    """A recorded output as the ``recorded`` backend returns it, with when it was logged."""

    result: BackendResult
    #: the output message's log time (the recorder's clock)
    log_time_ns: int


@dataclass(frozen=True, slots=True)
class OutputReader:
    """How the ``recorded`` backend reads one message type (see the module docstring)."""

    task: str
    read: Callable[[RawMessage], RecordedMessage]
    candidate: bool = True


def _read_detection2d_array(raw: RawMessage) -> RecordedMessage:
    found = decode_detections(raw)
    return RecordedMessage(
        found.frame_id, found.stamp_ns, BackendResult(found.detections), found.nonfinite
    )


#: message type (ROS 2 spelling) -> its reader. Adding a task's recorded output is one entry.
RECORDED_READERS: Mapping[str, OutputReader] = {
    'vision_msgs/msg/Detection2DArray': OutputReader('detections', _read_detection2d_array),
}


def _ros2_name(msgtype: str) -> str:
    package, _, name = msgtype.partition('/')
    return msgtype if '/msg/' in msgtype or not name else f'{package}/msg/{name}'


def output_reader(msgtype: str) -> OutputReader | None:
    """The reader of recorded outputs of ``msgtype`` (ROS 1 or ROS 2 spelling); None if none."""
    return RECORDED_READERS.get(_ros2_name(msgtype))


def recorded_candidates(topics: Mapping[str, str], exclude: str | None) -> list[str]:
    """The topics (name -> msgtype) that may be picked without ``--recorded-topic``: of a
    ``candidate`` type, other than ``exclude`` (the ground-truth topic)."""
    return [
        name
        for name, msgtype in topics.items()
        if name != exclude and (reader := output_reader(msgtype)) is not None and reader.candidate
    ]


def read_recorded_outputs(
    source: MessageSource, topic: str, msgtype: str, notes: list[str] | None = None
) -> dict[tuple[str, int], RecordedOutput]:
    """The outputs recorded on ``topic`` keyed by (frame_id, stamp_ns), each with its log time.

    Messages the reader cannot decode are skipped; when two share a key the later one is kept.
    ``notes`` gets a line for values left out (``RecordedMessage.left_out``) and one for messages
    skipped. ``DecodeError`` when ``msgtype`` has no reader.
    """
    reader = output_reader(msgtype)
    if reader is None:
        types = ', '.join(sorted(RECORDED_READERS))
        msg = f'{topic} is a {msgtype} topic; recorded outputs are read from: {types}'
        raise DecodeError(msg)
    table: dict[tuple[str, int], RecordedOutput] = {}
    left_out = with_left_out = skipped = 0
    first_error = ''
    for raw in source.messages(topics=[topic]):
        try:
            found = reader.read(raw)
        except DecodeError as err:
            skipped += 1
            first_error = first_error or str(err)
            continue
        table[(found.frame_id, found.stamp_ns)] = RecordedOutput(found.result, raw.log_time_ns)
        if found.left_out:
            left_out += found.left_out
            with_left_out += 1
    if notes is not None and left_out:
        if reader.task == 'detections':
            what = f'{left_out} detection(s) with a NaN or infinite box or score'
        else:
            what = f'{left_out} unusable value(s)'
        notes.append(f'{topic}: left out {what} in {with_left_out} message(s)')
    if notes is not None and skipped:
        notes.append(f'{topic}: {skipped} recorded message(s) could not be read: {first_error}')
    return table
