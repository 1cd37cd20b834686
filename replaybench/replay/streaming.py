"""Streaming scores: every frame scored against the output a robot would have had in hand.

On the robot the planner at time t uses the latest output *finished* at t, computed from an
older frame; offline scores compare each output with the truth of its own frame, as if the
world had waited. After each pass (never beside timed frames) ``pick_outputs`` chooses, for
every frame of a (backend, topic), the output that was the latest finished at the frame's
release time: at a timed rate on the replay clock (release and finish times of the pass's
log), for a backend replaying recorded outputs (``recorded``) on the recording's clock (the
frame's log time, and the log time of each recorded output). Before the first output a frame
has none (scored as an empty output). At ``--rate max`` a frame is released as soon as the backend is
free: there is no clock a robot would share, and the scores are refused (``REFUSED_AT_MAX``).

What the picks are scored to is the task's (``Task.streaming``, ``'module:attr'`` of a
callable ``(recorder, backend, topic, picks) -> metrics``; ``Task.streaming_metrics`` names
them, each with the offline figure it is the streaming form of): the engine picks outputs by
time and never knows the task. A frame pushed out of its queue is scored too (against the
output in use when it was released); its header is read again after the passes to find its
truth (``header_keys``).
"""

from __future__ import annotations

import bisect
import contextlib
from typing import TYPE_CHECKING, NamedTuple, Protocol

from replaybench.errors import DecodeError

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    from replaybench.replay.inputs import OpenedInput
    from replaybench.results.model import SummaryRow

__all__ = [
    'REFUSED_AT_MAX',
    'Pick',
    'StreamFrame',
    'header_keys',
    'pick_outputs',
    'streaming_scores',
]

#: The warning of a run at ``--rate max`` whose backends would have streaming scores.
REFUSED_AT_MAX = (
    'streaming scores refused at --rate max: a frame is released as soon as the backend is '
    'free, on no clock a robot would share; replay at recorded, a factor (1x) or a fixed rate '
    '(30hz) for them'
)

#: (topic, seq, log_time_ns, stamp_ns, frame_id); stamp None and frame_id '' for a frame that
#: was not decoded in its pass (``replaybench.replay.passes.FrameKey``)
FrameKey = tuple[str, int, int, 'int | None', str]


class StreamFrame(NamedTuple):
    """One frame of a pass's stream: released at ``released`` (s); ``available`` is when its
    output was finished (s, the same clock), None where it has none (dropped, not decoded)."""

    key: FrameKey
    released: float
    available: float | None


class Pick(NamedTuple):
    """A frame scored (``frame``) and the frame whose output was in use at its release
    (``output``; None before the first output), with the output's age: the release time of
    ``frame`` minus that of ``output`` (s; None without output)."""

    input: int
    frame: FrameKey
    output: FrameKey | None
    age_s: float | None


def pick_outputs(number: int, frames: Sequence[StreamFrame]) -> list[Pick]:
    """For each frame of one topic of one pass (in log order), the output that was the latest
    finished at its release time (finished at or before it); ties go to the later frame."""
    done = sorted(
        ((f.available, f.released, i) for i, f in enumerate(frames) if f.available is not None),
    )
    finished = [t for t, _, _ in done]
    picks: list[Pick] = []
    for frame in frames:
        n = bisect.bisect_right(finished, frame.released)
        if n == 0:
            picks.append(Pick(number, frame.key, None, None))
            continue
        _, released, index = done[n - 1]
        picks.append(Pick(number, frame.key, frames[index].key, frame.released - released))
    return picks


def header_keys(inp: OpenedInput, topic: str, seqs: Iterable[int]) -> Mapping[int, tuple[int, str]]:
    """(stamp_ns, frame_id) of the frames ``seqs`` of ``topic``, read again from the input
    after the passes (frames pushed out of their queue were never decoded), from their headers
    (``image_header``: their pixels are not decoded); a frame without a readable header is
    absent (it is not scored)."""
    from replaybench.decode.image import image_header

    wanted = set(seqs)
    found: dict[int, tuple[int, str]] = {}
    if not wanted:
        return found
    for raw in inp.source.messages(topics=[topic], start_ns=inp.start_ns, end_ns=inp.end_ns):
        if raw.seq not in wanted:
            continue
        with contextlib.suppress(DecodeError):
            found[raw.seq] = image_header(raw)
        wanted.discard(raw.seq)
        if not wanted:
            break
    return found


class Recorder(Protocol):
    """What the scores read of the run's ``replaybench.replay.recording.Recorder`` (and what a
    task's scorer is given: its kept outputs besides)."""

    @property
    def inputs(self) -> Sequence[OpenedInput]: ...
    @property
    def picks(self) -> Mapping[tuple[str, str], list[Pick]]: ...
    @property
    def stream_tasks(self) -> Mapping[tuple[str, str], str]: ...
    @property
    def streaming_refused(self) -> set[str]: ...


def _resolved(recorder: Recorder, picks: Sequence[Pick]) -> list[Pick]:
    """``picks`` with the header (stamp, frame_id) of every frame not decoded in its pass read
    again (``header_keys``); a frame whose header cannot be read is left out."""
    missing: dict[tuple[int, str], list[int]] = {}
    for pick in picks:
        if pick.frame[3] is None:
            missing.setdefault((pick.input, pick.frame[0]), []).append(pick.frame[1])
    headers = {
        (number, topic): header_keys(recorder.inputs[number], topic, seqs)
        for (number, topic), seqs in missing.items()
    }
    out: list[Pick] = []
    for pick in picks:
        topic, seq, log_time_ns, stamp_ns, _ = pick.frame
        if stamp_ns is None:
            found = headers[pick.input, topic].get(seq)
            if found is None:
                continue
            pick = pick._replace(frame=(topic, seq, log_time_ns, found[0], found[1]))
        out.append(pick)
    return out


def streaming_scores(recorder: Recorder, row: SummaryRow) -> dict[str, float | None]:
    """The streaming metrics of a (backend label, topic) row: its task's scores of the picks
    (``Task.streaming``); every one None where the scores were refused (``--rate max``) and the
    row has offline figures of the task; empty for a row without them, without picks or of a
    task without streaming scores."""
    from replaybench.tasks import get_task, load_view

    backend, topic = row.backend, row.topic
    name = recorder.stream_tasks.get((backend, topic))
    if name is None:
        return {}
    task = get_task(name)
    names = tuple(getattr(task, 'streaming_metrics', ()))
    target: str | None = getattr(task, 'streaming', None)
    if not names or target is None:
        return {}
    if backend in recorder.streaming_refused:
        offline = [m.name for m in task.metrics if m.name not in names]
        scored = any(row.metric(metric) is not None for metric in offline)
        return dict.fromkeys(names) if scored else {}
    picks = recorder.picks.get((backend, topic))
    if not picks:
        return {}
    found = load_view(task, target, 'streaming')(
        recorder, backend, topic, _resolved(recorder, picks)
    )
    return {metric: found.get(metric) for metric in names}
