"""The ``recorded`` backend: detections a robot already recorded in the bag, scored like a backend.

It runs nothing: for each replayed image it returns the Detection2DArray recorded on the chosen
topic with the same frame_id and header stamp (none when there is no such message). Its rows carry
no latency or stage times, since the detector ran on the robot, not here; its accuracy and its
agreement with the other backends are what it is for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.types import BackendResult, Detection, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.backends.base import RecordedDetections
    from replaybench.types import Frame

__all__ = ['RecordedBackend']

_NO_STAGES = StageTimes()


class RecordedBackend:
    """Returns the detections recorded in the bag for each frame (matched by frame_id + stamp)."""

    name: ClassVar[str] = 'recorded'
    description: ClassVar[str] = (
        'detections recorded in the bag (a Detection2DArray topic, --recorded-topic), '
        'scored as a backend'
    )
    #: The runner leaves latency and stage columns empty for this backend.
    measures_latency: ClassVar[bool] = False
    #: The runner reads the recorded topic and calls ``prepare`` with it.
    uses_recorded_detections: ClassVar[bool] = True

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        self.topic = ''
        self._table: Mapping[tuple[int, str, int], tuple[Detection, ...]] = {}
        self._matched = 0
        self._missing = 0

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def prepare(self, recorded: RecordedDetections) -> None:
        """Take the recorded detections, keyed by (input index, frame_id, stamp_ns)."""
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
        return BackendResult(found, _NO_STAGES)

    def info(self) -> dict[str, Any]:
        return {
            'topic': self.topic,
            'messages': len(self._table),
            'frames_matched': self._matched,
            'frames_without_recorded_detections': self._missing,
            'latency': 'not measured: the detector ran when the bag was recorded',
        }

    def close(self) -> None:
        """Nothing to release."""
