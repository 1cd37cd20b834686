"""Perception outputs recorded in a bag (what the robot's own nodes published): how one is read.

The ``recorded`` backend replays a recorded output topic as if a backend had produced it. Which
message types it reads is one table, ``replaybench.replay.recorded.RECORDED_READERS``: a message
type (ROS 2 spelling, ``vision_msgs/msg/Detection2DArray``) -> an ``OutputReader``. This module
holds the reader's parts and two of the readers:

* ``read_detection2d_array`` (task ``detections``): a Detection2DArray's boxes, as a detector
  returns them;
* ``read_label_mask`` (task ``segmentation``): a ``mono8`` (or ``mono16`` with ids up to 255)
  Image of class ids, as the ``BackendResult.mask`` of a segmentation backend; an Image that is
  not a label mask (``rgb8``, a ``16UC1`` depth image) is refused with a ``UsageError``.

The tags' reader (AprilTagDetectionArray -> ``TagResult``) is
``replaybench.fiducials.recorded.read_tag_array_output``. An ``OutputReader`` provides:

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
  ``TagResult`` so the frame counts against tag recall; no mask, so the frame is not scored).

``read_recorded_outputs`` reads a topic through its reader into a table keyed by (frame_id,
stamp_ns), keeping each output's log time: the time the recorder logged it, from which
``replaybench.results.recorded_latency`` derives the recorded latency.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from replaybench.decode.detections import decode_detections
from replaybench.errors import DecodeError, UsageError
from replaybench.types import BackendResult, LabelMask

if TYPE_CHECKING:
    from collections.abc import Callable

    from replaybench.decode.kinds import MessageSource
    from replaybench.types import RawMessage

__all__ = [
    'MASK_ENCODINGS',
    'OutputReader',
    'RecordedMessage',
    'RecordedOutput',
    'read_detection2d_array',
    'read_label_mask',
    'read_recorded_outputs',
]

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

    @property
    def noun(self) -> str:
        """What the outputs are called: ``outputs``, else the task's name."""
        return self.outputs or self.task


def read_detection2d_array(raw: RawMessage) -> RecordedMessage:
    found = decode_detections(raw)
    return RecordedMessage(
        found.frame_id, found.stamp_ns, BackendResult(found.detections), found.nonfinite
    )


#: Image encodings read as label masks (as ``decode_image`` names them).
MASK_ENCODINGS = ('mono8', 'mono16')


def read_label_mask(raw: RawMessage) -> RecordedMessage:
    """A mono8 / mono16 Image of class ids as a segmentation backend's mask (class names are
    not recorded: ids stand for them). ``UsageError`` for an image that is not a label mask,
    ``DecodeError`` for a mono16 mask with an id above 255. The masks of the topic are held for
    the run, one ``H x W`` byte array each, as a pass holds its backends' masks."""
    import numpy as np

    from replaybench.decode.image import decode_image

    frame = decode_image(raw)
    if frame.encoding not in MASK_ENCODINGS or frame.is_depth:
        msg = (
            f'{raw.topic} holds {frame.source_encoding} images, not label masks (mono8 or mono16 '
            'class ids): the recorded backend reads an Image topic as label masks'
        )
        raise UsageError(msg)
    image = frame.image.reshape(frame.height, frame.width)
    if frame.encoding == 'mono16' and image.size and int(image.max()) > 255:
        msg = f'a mask with class id {int(image.max())}: ids above 255 are not read'
        raise DecodeError(msg)
    labels = np.array(image, dtype=np.uint8, order='C')
    mask = LabelMask(labels, ())
    return RecordedMessage(frame.frame_id, frame.stamp_ns, BackendResult((), mask=mask))


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
        if reader.task == 'detections':
            what = f'{left_out} detection(s) with a NaN or infinite box or score'
        elif reader.task == 'tags':
            what = f'{left_out} tag(s) with a NaN or infinite corner'
        else:
            what = f'{left_out} unusable value(s)'
        notes.append(f'{topic}: left out {what} in {with_left_out} message(s)')
    if notes is not None and skipped:
        notes.append(f'{topic}: {skipped} recorded message(s) could not be read: {first_error}')
    return table
