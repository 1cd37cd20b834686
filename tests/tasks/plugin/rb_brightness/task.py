"""The ``brightness`` task: what replaybench is told of it (``replaybench.tasks.Task``)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.tasks import MetricSpec

from . import MSGTYPE, TRUTH_TOPIC

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.decode.recorded import OutputReader
    from replaybench.tasks import TruthInput

__all__ = ['TASK', 'BrightnessTask']

#: (frame_id, header stamp) -> the frame's true mean grey level
Truth = dict[tuple[str, int], float]


class BrightnessTask:
    """Mean grey level against the bag's truth: one metric, the mean absolute error."""

    name: ClassVar[str] = 'brightness'
    metrics: ClassVar[tuple[MetricSpec, ...]] = (
        MetricSpec(
            'brightness_error',
            'brightness error (grey levels)',
            'bright. err',
            'lower',
            fmt='.3f',
            sweep=True,
            main=True,
        ),
    )
    #: frames.csv's column of it (after the known ones): each frame's absolute error
    frame_columns: ClassVar[tuple[str, ...]] = ('brightness_abs_error',)
    #: the recorded backend reads no output of this task
    recorded_readers: ClassVar[Mapping[str, OutputReader]] = {}
    #: the part of recording a frame (``replaybench.tasks.TaskRecording``)
    recording: ClassVar[str] = 'rb_brightness.recording:recording'

    def truth_topics(self, options: Any) -> frozenset[str]:
        del options
        return frozenset((TRUTH_TOPIC,))

    def load_truth(self, config: Any) -> object | None:
        del config
        return None

    def open_truth(
        self, inp: TruthInput, options: Any, loaded: object | None, notes: list[str]
    ) -> object | None:
        """The input's truth by (frame_id, stamp); None where it has no truth topic."""
        del options, loaded
        if not any(t.name == TRUTH_TOPIC for t in inp.source.topics()):
            return None
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS2_HUMBLE)
        truth: Truth = {}
        bad = 0
        for raw in inp.source.messages(topics=[TRUTH_TOPIC]):
            if raw.msgtype != MSGTYPE:
                bad += 1
                continue
            msg: Any = store.deserialize_cdr(bytes(raw.data), MSGTYPE)
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            truth[(msg.header.frame_id, stamp)] = float(msg.illuminance)
        if bad:
            notes.append(f'{TRUTH_TOPIC}: {bad} message(s) are not {MSGTYPE}; left out')
        return truth


TASK = BrightnessTask()
