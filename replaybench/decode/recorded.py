"""Perception outputs recorded in a bag (what the robot's own nodes published): how one is read.

The ``recorded`` backend replays a recorded output topic as if a backend had produced it. Which
message types it reads, each task declares (``Task.recorded_readers``: a message type in ROS 2
spelling, ``vision_msgs/msg/Detection2DArray``, -> an ``OutputReader``; the readers are in
``replaybench/tasks/<task>/recorded.py``); ``replaybench.replay.recorded.RECORDED_READERS``
gathers them from the registered tasks. This module holds what every reader shares. An
``OutputReader`` provides:

* ``task``: the task type the output belongs to (``'detections'``); ``outputs``: what its
  messages hold, in notes and errors (``'detections'``, ``'tags'``, ``'masks'``);
* ``read(raw) -> RecordedMessage``: the message's header (frame_id, stamp) and the task's result
  for it, as the ``BackendResult`` a replayed backend of that task would return for the frame
  (``left_out``: values dropped as unusable, e.g. non-finite boxes); raises ``DecodeError`` for a
  message it cannot read (the message is skipped);
* ``candidate``: True when a topic of this type is picked without ``--recorded-topic`` if it is
  the only such topic besides the ground truth (False for types also used for other data, such
  as ``sensor_msgs/msg/Image``, which camera topics use too);
* ``missing``: what a frame without a recorded output gets (no detections, an empty
  ``TagResult`` so the frame counts against tag recall; no mask, so the frame is not scored);
* ``unusable``: what the values ``read`` leaves out are, in the input's notes;
* ``producer``: who made the outputs on the robot (the ``latency`` line of the backend's info).

Whether a frame's boxes are scored against box ground truth is the task's to say (its
``TaskRecording.scores_boxes``, ``replaybench.replay.recording``), for recorded outputs as for
a replayed backend's.

``read_recorded_outputs`` reads a topic through its reader into a table keyed by (frame_id,
stamp_ns), keeping each output's log time: the time the recorder logged it, from which
``replaybench.results.recorded_latency`` derives the recorded latency.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from replaybench.errors import DecodeError
from replaybench.types import BackendResult

if TYPE_CHECKING:
    from collections.abc import Callable

    from replaybench.decode.kinds import MessageSource
    from replaybench.types import RawMessage

__all__ = ['OutputReader', 'RecordedMessage', 'RecordedOutput', 'read_recorded_outputs']

_NOTHING = BackendResult(())


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
    #: what its messages hold, plural (notes, errors, info keys); the task's name when empty
    outputs: str = ''
    #: the result of a frame without a recorded output
    missing: BackendResult = _NOTHING
    #: what the values ``read`` leaves out are (``RecordedMessage.left_out``), in notes
    unusable: str = 'unusable value(s)'
    #: who made the outputs on the robot, in the ``latency`` line of the backend's info
    producer: str = 'the node'
    #: the task of an input's outputs where some of their boxes carry an id
    #: (``Detection.id``: a tracker's tracks); None: always ``task``
    identified_task: str | None = None

    @property
    def noun(self) -> str:
        """What the outputs are called: ``outputs``, else the task's name."""
        return self.outputs or self.task


def read_recorded_outputs(
    source: MessageSource, topic: str, reader: OutputReader, notes: list[str] | None = None
) -> dict[tuple[str, int], RecordedOutput]:
    """The outputs recorded on ``topic`` (read by ``reader``) keyed by (frame_id, stamp_ns),
    each with its log time.

    Messages the reader cannot decode are skipped; when two share a key the later one is kept.
    ``notes`` gets a line for values left out (``RecordedMessage.left_out``) and one for messages
    skipped. The reader's ``UsageError`` (a topic not of its task at all) goes through.
    """
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
        what = f'{left_out} {reader.unusable}'
        notes.append(f'{topic}: left out {what} in {with_left_out} message(s)')
    if notes is not None and skipped:
        notes.append(f'{topic}: {skipped} recorded message(s) could not be read: {first_error}')
    return table
