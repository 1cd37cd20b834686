"""The ``recorded`` backend: outputs a robot already recorded in the bag, scored like a backend.

It runs nothing: for each replayed image it returns the output recorded on the chosen topic with
the same frame_id and header stamp, read by the topic's type (the tasks' readers,
``replaybench.replay.recorded.RECORDED_READERS``): a Detection2DArray's boxes, an
AprilTagDetectionArray's tags (a ``TagResult``, as the tag backends return it) or a label-mask
Image's mask (as a segmentation backend returns it). A frame without such a message gets its
reader's ``missing`` result: no detections, no tags (both scored as misses), no mask (not
scored). Its rows carry no
replay latency or stage times, since the node ran on the robot, not here; the runner gives
them the recorded latency instead, from the output's log time against its image's header stamp
and log time (``replaybench.results.recorded_latency``). Its accuracy, its agreement with the
other backends and its recorded latency are what it is for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import BackendError
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.backends.base import RecordedDetections
    from replaybench.decode.recorded import OutputReader, RecordedOutput
    from replaybench.types import Frame

__all__ = ['RecordedBackend']

_NO_STAGES = StageTimes()
_NOTHING = BackendResult((), _NO_STAGES)


class RecordedBackend:
    """Returns the output recorded in the bag for each frame (matched by frame_id + stamp)."""

    name: ClassVar[str] = 'recorded'
    description: ClassVar[str] = (
        'outputs recorded in the bag (a Detection2DArray, AprilTagDetectionArray or label-mask '
        'Image topic, --recorded-topic), scored as a backend, with their recorded latency'
    )
    #: The runner leaves latency and stage columns empty for this backend.
    measures_latency: ClassVar[bool] = False
    #: The runner reads the recorded topic and calls ``prepare`` with it.
    uses_recorded_detections: ClassVar[bool] = True
    #: ``detect`` never reads ``frame.camera_info``.
    reads_camera_info: ClassVar[bool] = False

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        if self.options.extra:
            msg = f'recorded: unknown option {sorted(self.options.extra)[0]!r} (it takes none)'
            raise BackendError(msg)
        self.topic = ''
        self._table: Mapping[tuple[int, str, int], RecordedOutput] = {}
        self._readers: Mapping[int, OutputReader] = {}
        self._tracked: set[int] = set()
        self._matched = 0
        # frames without a recorded output, by what the outputs are ('detections', 'tags')
        self._missing: dict[str, int] = {'detections': 0}

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def prepare(self, recorded: RecordedDetections) -> None:
        """Take the recorded outputs, keyed by (input index, frame_id, stamp_ns)."""
        self.topic = recorded.topic
        self._table = recorded.table
        self._readers = recorded.readers or {}
        #: inputs whose recorded boxes carry ids (``Detection2D.id``): a tracker's tracks
        self._tracked = {
            index for (index, _, _), found in self._table.items() if _has_ids(found.result)
        }
        self._missing = {self._noun(index): 0 for index in sorted(self._readers) or [0]}

    def _noun(self, input_index: int) -> str:
        reader = self._readers.get(input_index)
        return 'detections' if reader is None else reader.noun

    def task_of(self, input_index: int) -> str:
        """The task of the outputs recorded in input ``input_index``: its topic's reader's
        (``Backend.task``); boxes for an input without a reader; tracks for boxes of which
        some carry an id."""
        reader = self._readers.get(input_index)
        if reader is None:
            return 'detections'
        if reader.identified_task is not None and input_index in self._tracked:
            return reader.identified_task  # boxes that carry ids are tracks
        return reader.task

    def open(self) -> None:
        """Nothing to load: ``prepare`` gave the recorded messages."""

    def detect(self, frame: Frame) -> BackendResult:
        found = self._table.get((frame.input_index, frame.frame_id, frame.stamp_ns))
        if found is None:
            noun = self._noun(frame.input_index)
            self._missing[noun] = self._missing.get(noun, 0) + 1
            reader = self._readers.get(frame.input_index)
            return _NOTHING if reader is None else reader.missing
        mask = found.result.mask
        if mask is not None and mask.labels.shape != (frame.height, frame.width):
            h, w = mask.labels.shape
            msg = (
                f'{self.topic}: the recorded mask of {frame.topic} #{frame.seq} is {w}x{h}, its '
                f'image {frame.width}x{frame.height}: masks are scored at their image size'
            )
            raise BackendError(msg)
        self._matched += 1
        return found.result

    def info(self) -> dict[str, Any]:
        # who made the outputs on the robot, one per task (by the task's name)
        producers = {r.task: r.producer for r in self._readers.values()}
        made_by = ' and '.join(producers[task] for task in sorted(producers)) or 'the detector'
        return {
            'topic': self.topic,
            'messages': len(self._table),
            'frames_matched': self._matched,
            **{f'frames_without_recorded_{noun}': n for noun, n in self._missing.items()},
            'latency': f'not measured: {made_by} ran when the bag was recorded',
            'recorded_latency': (
                'from the recording: capture_to_output_ms (output log time - image header '
                'stamp) and pipeline_ms (output log time - image log time)'
            ),
        }

    def close(self) -> None:
        """Nothing to release."""


def _has_ids(result: BackendResult) -> bool:
    return any(d.id for d in result.detections)
