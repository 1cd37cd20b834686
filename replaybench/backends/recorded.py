"""The ``recorded`` backend: outputs a robot already recorded in the bag, scored like a backend.

It runs nothing: for each replayed image it returns the output recorded on the chosen topic with
the same frame_id and header stamp (none when there is no such message), read by the topic's type
(``replaybench.decode.recorded.RECORDED_READERS``; Detection2DArray today). Its rows carry no
replay latency or stage times, since the detector ran on the robot, not here; the runner gives
them the recorded latency instead, from the output's log time against its image's header stamp
and log time (``replaybench.results.recorded_latency``). Its accuracy, its agreement with the
other backends and its recorded latency are what it is for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.backends.base import RecordedDetections
    from replaybench.decode.recorded import RecordedOutput
    from replaybench.types import Frame

__all__ = ['RecordedBackend']

_NO_STAGES = StageTimes()


class RecordedBackend:
    """Returns the detections recorded in the bag for each frame (matched by frame_id + stamp)."""

    name: ClassVar[str] = 'recorded'
    description: ClassVar[str] = (
        'outputs recorded in the bag (a Detection2DArray topic, --recorded-topic), '
        'scored as a backend, with their recorded latency'
    )
    #: The runner leaves latency and stage columns empty for this backend.
    measures_latency: ClassVar[bool] = False
    #: The runner reads the recorded topic and calls ``prepare`` with it.
    uses_recorded_detections: ClassVar[bool] = True

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        self.topic = ''
        self._table: Mapping[tuple[int, str, int], RecordedOutput] = {}
        self._matched = 0
        self._missing = 0

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def prepare(self, recorded: RecordedDetections) -> None:
        """Take the recorded outputs, keyed by (input index, frame_id, stamp_ns)."""
        self.topic = recorded.topic
        self._table = recorded.table

    def open(self) -> None:
        """Nothing to load: ``prepare`` gave the recorded messages."""

    def detect(self, frame: Frame) -> BackendResult:
        found = self._table.get((frame.input_index, frame.frame_id, frame.stamp_ns))
        if found is None:
            self._missing += 1
            return BackendResult((), _NO_STAGES)
        self._matched += 1
        return found.result

    def info(self) -> dict[str, Any]:
        return {
            'topic': self.topic,
            'messages': len(self._table),
            'frames_matched': self._matched,
            'frames_without_recorded_detections': self._missing,
            'latency': 'not measured: the detector ran when the bag was recorded',
            'recorded_latency': (
                'from the recording: capture_to_output_ms (output log time - image header '
                'stamp) and pipeline_ms (output log time - image log time)'
            ),
        }

    def close(self) -> None:
        """Nothing to release."""
