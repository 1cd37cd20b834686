"""The runner's side of recorded outputs: which topic the ``recorded`` backend replays, its
outputs read by type (``replaybench.decode.recorded``), and each frame's recorded latency
(``replaybench.results.recorded_latency``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.decode.recorded import (
    RECORDED_READERS,
    output_reader,
    read_recorded_outputs,
    recorded_candidates,
)
from replaybench.errors import UsageError
from replaybench.results.recorded_latency import RecordedTimes, recorded_times

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    from replaybench.decode.recorded import RecordedOutput
    from replaybench.sources import Source
    from replaybench.types import TopicInfo

__all__ = ['NOT_RECORDED', 'frame_recorded_times', 'read_recorded', 'recorded_note']

#: The recorded-output columns of a frame of a replayed (timed) backend: all empty.
NOT_RECORDED = RecordedTimes(None, None, None)


def read_recorded(
    path: Path,
    source: Source,
    topics: Sequence[TopicInfo],
    wanted: str | None,
    ground_truth_topic: str | None,
    notes: list[str],
) -> tuple[str, dict[tuple[str, int], RecordedOutput]]:
    """The topic the ``recorded`` backend replays (``wanted``, i.e. --recorded-topic, or the
    only candidate besides the ground truth) and its outputs keyed by (frame_id, stamp_ns).

    ``UsageError`` when the topic is not in the file, is of a type without a reader, or cannot
    be picked alone."""
    types = {t.name: t.msgtype for t in topics}
    if wanted is not None:
        if wanted not in types:
            msg = f'{path}: --recorded-topic {wanted} is not in this file'
            raise UsageError(msg)
        if output_reader(types[wanted]) is None:
            readable = ', '.join(sorted(RECORDED_READERS))
            msg = (
                f'{path}: --recorded-topic {wanted} is a {types[wanted]} topic; the recorded '
                f'backend reads {readable}'
            )
            raise UsageError(msg)
        topic = wanted
    else:
        candidates = recorded_candidates(types, ground_truth_topic)
        if len(candidates) != 1:
            found = ', '.join(candidates) if candidates else 'none'
            types_read = ', '.join(sorted(RECORDED_READERS))
            msg = (
                f'{path}: the recorded backend needs --recorded-topic TOPIC (topics it can pick '
                f'alone besides the ground truth: {found}; it reads {types_read})'
            )
            raise UsageError(msg)
        topic = candidates[0]
    return topic, read_recorded_outputs(source, topic, types[topic], notes)


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


def recorded_note(times: RecordedTimes) -> str:
    """frames.csv's note of a frame of a backend that replays recorded outputs."""
    base = 'recorded detections: latency not measured'
    extra = times.note
    return f'{base}; {extra}' if extra else base
