"""The ``brightness`` task's part of a run (``replaybench.tasks.TaskRecording``): each frame's
level written into outputs.mcap and scored against the truth; a row's mean absolute error."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.tasks import TaskRecordingBase

from . import MSGTYPE

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.sinks.writer import OutputWriter
    from replaybench.types import BackendResult

__all__ = ['BrightnessRecording', 'output_topic', 'recording']


def output_topic(backend: str, image_topic: str) -> str:
    """``/replaybench/<backend><image topic>/brightness``."""
    return f'/replaybench/{backend.replace("-", "_")}{image_topic}/brightness'


class BrightnessRecording(TaskRecordingBase):
    """Each (backend, topic)'s absolute errors, in replay order."""

    def __init__(self) -> None:
        self.errors: dict[tuple[str, str], list[float]] = {}
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)

    def frame(
        self,
        writer: OutputWriter,
        label: str,
        inp: Any,
        key: tuple[str, int, int, int, str],
        result: BackendResult,
    ) -> Mapping[str, Any]:
        topic, _, log_time_ns, stamp_ns, frame_id = key
        level = float(result.output)
        if writer.keeps:
            types: Any = self.store.types
            msg = types[MSGTYPE](
                header=types['std_msgs/msg/Header'](
                    stamp=types['builtin_interfaces/msg/Time'](
                        sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9
                    ),
                    frame_id=frame_id,
                ),
                illuminance=level,
                variance=0.0,
            )
            data = bytes(self.store.serialize_cdr(msg, MSGTYPE))
            writer.add_message(output_topic(label, topic), MSGTYPE, log_time_ns, data)
        truth = inp.truth.get('brightness')
        expected = None if truth is None else truth.get((frame_id, stamp_ns))
        if expected is None:
            return {}
        error = abs(level - expected)
        self.errors.setdefault((label, topic), []).append(error)
        return {'brightness_abs_error': error}

    def summary(self, backend: str, topic: str) -> Mapping[str, Any] | None:
        errors = self.errors.get((backend, topic))
        if not errors:
            return None
        return {'brightness_error': sum(errors) / len(errors)}


def recording(recorder: object) -> BrightnessRecording:
    del recorder
    return BrightnessRecording()
