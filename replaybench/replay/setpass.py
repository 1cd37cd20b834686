"""The pass of a backend that takes frame sets (``Backend.takes_frame_sets``, with ``--sync``):
each synchronised set of an input given to it as one ``FrameSet`` (``replaybench.types``).

A set is released when the replay reads its last member, at that member's log time (a live
``message_filters`` synchronizer fires on the last member's arrival); at a fixed rate the k-th
set at k / Hz. The sets wait in one queue of ``--queue-depth`` for the input's set stream,
keyed by the reference topic (``replay_timed``: newest kept); at ``max`` they follow each other
back to back. Every member is decoded before the backend's call, and the set's read + decode
time is their sum (at ``max`` with the reading of its messages, as a frame's is). The frames in
no set are read past and never given to the backend (run.json's ``sync`` counts them). Its log
entries are keyed by the set's reference frame (the first topic's), so that the recording
(``replaybench.replay.recording``) makes one frames.csv row per set, and writes its result,
under that frame's key.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

from replaybench.backends.base import DEFAULT_TASK
from replaybench.errors import DecodeError
from replaybench.replay.config import default_warmup
from replaybench.replay.passes import LogEntry, Pass
from replaybench.replay.scheduler import replay_timed
from replaybench.types import FrameSet

if TYPE_CHECKING:
    from collections.abc import Iterator

    from replaybench.backends.base import Backend, FrameSetBackend
    from replaybench.replay.inputs import OpenedInput
    from replaybench.replay.pairing import InputPairing
    from replaybench.replay.passes import Replay
    from replaybench.replay.rate import Rate
    from replaybench.types import Frame, RawMessage

    #: a synchronised set's member messages, in its topics' order (the reference first)
    Members = tuple[RawMessage, ...]

__all__ = ['SetPass']

_NS = 1_000_000_000


class SetPass(Pass):
    """One backend that takes frame sets over one input: ``sets``, the input's synchronised
    sets (``replaybench.replay.pairing``), each given to it as one ``FrameSet``; one
    ``LogEntry`` per set. Its warm-up is counted in sets (``warmup_frames``)."""

    def __init__(
        self,
        replay: Replay,
        label: str,
        backend: Backend,
        inp: OpenedInput,
        sets: InputPairing,
        repeat: int = 0,
        task: str = DEFAULT_TASK,
    ) -> None:
        super().__init__(replay, label, backend, inp, repeat, task)
        self.sets = sets
        self.set_warmup = _set_warmup(replay, len(sets.grouping.sets))
        # the log time of the pass's first message: where the replay clock starts
        self._first_log: int | None = None

    def warmup_frames(self, topic: str) -> int:  # noqa: ARG002 - one stream, whatever topic
        """The warm-up sets of the set stream (its rows carry the reference topic)."""
        return self.set_warmup

    def run(self) -> None:
        """The sets at the run's rate, after a warm-up set where they are too few for warm-up
        sets."""
        self.replay.check_stop()
        self.run_sets(self.replay.options.rate)

    def run_sets(self, rate: Rate) -> None:
        """Each synchronised set of the input as one ``FrameSet``, after a warm-up set where
        the sets are too few for warm-up sets: at a timed rate released when its last member
        is due (``replay_timed``, one queue for the input's set stream, keyed by the reference
        topic), at ``max`` back to back, each released when the previous one is done."""
        self._warm_first_set()
        clock = self.replay.clock
        self.t0 = clock.now()
        if rate.timed:
            replay_timed(
                self._set_releases(rate),
                clock=clock,
                queue_depth=self.replay.options.queue_depth,
                process=self.process_set,
                drop=self.drop_set,
            )
            return
        now = clock.now
        release = now()
        for members in self._completed_sets():
            self.replay.check_stop()
            # released when the previous set is done: reading its messages is its read time
            self.process_set(members, release, release)
            release = now()

    def _completed_sets(self, *, counted: bool = True) -> Iterator[Members]:
        """Each set's member messages (in its topics' order) as the replay completes it, on
        reading its last member; frames in no set are read past (``counted``: as replayed, for
        the progress)."""
        members = self.sets.members()
        width = len(self.sets.grouping.topics)
        pending: dict[int, list[RawMessage | None]] = {}
        missing: dict[int, int] = {}
        for raw in self.messages():
            if self._first_log is None:
                self._first_log = raw.log_time_ns
            found = members.get((raw.topic, raw.seq))
            if found is None:
                if counted:
                    self.replay.advance(1)  # no partner: never given to this backend
                continue
            number, place = found
            slots = pending.get(number)
            if slots is None:
                slots = pending[number] = [None] * width
                missing[number] = width
            slots[place] = raw
            missing[number] -= 1
            if not missing[number]:
                del pending[number], missing[number]
                yield tuple(m for m in slots if m is not None)

    def _set_releases(self, rate: Rate) -> Iterator[tuple[float, str, Members]]:
        """Each set's release offset (s from the pass's start): its last member's log time
        (scaled), or the k-th set at k / Hz, never before the previous one."""
        last = 0.0
        for k, members in enumerate(self._completed_sets()):
            self.replay.check_stop()
            if rate.mode == 'fixed':
                offset = max(last, k / rate.hz)
            else:
                latest = max(m.log_time_ns for m in members)
                first = self._first_log if self._first_log is not None else latest
                offset = max(last, (latest - first) / _NS / rate.scale)
            last = offset
            yield offset, members[0].topic, members

    def _decode_set(self, members: Members) -> FrameSet:
        frames: list[Frame] = [self.decode(raw) for raw in members]
        return FrameSet(tuple(frames))

    def process_set(self, members: Members, release: float, start: float) -> None:
        """Decode every member and detect the set now: queued from ``release`` to ``start``;
        its read + decode time runs from ``start`` (at ``max``, the release: the reading of
        its messages included) to the backend's call. A member that does not decode skips the
        set, its row the reference frame's."""
        now = self.replay.clock.now
        detect = cast('FrameSetBackend', self.backend).detect
        try:
            frame_set = self._decode_set(members)
        except DecodeError as err:
            done = now()
            self.log.append(
                LogEntry.undecoded(
                    members[0], err, release, start, done, done - start, start - release
                )
            )
        else:
            t_detect = now()
            try:
                result = detect(frame_set)
            except Exception as err:
                raise self._detect_failed(frame_set.topic, frame_set.seq, err) from err
            done = now()
            self.log.append(
                LogEntry(
                    frame_set.reference[:5],
                    result,
                    release,
                    start,
                    t_detect - start,
                    t_detect,
                    done,
                    start - release,
                )
            )
        self.replay.advance(len(members))

    def drop_set(self, members: Members, release: float) -> None:
        """A set pushed out of its queue before the backend took it: its reference's row."""
        self.log.append(LogEntry.dropped(members[0], release))
        self.replay.advance(len(members))

    def _warm_first_set(self) -> None:
        """One detect on the first set that decodes, not timed, recorded or counted, where the
        sets are too few for warm-up sets (as ``warm_short_topics`` does for frames)."""
        if self.replay.options.warmup is not None or not self.measures_latency:
            return
        if self.set_warmup > 0:
            return
        detect = cast('FrameSetBackend', self.backend).detect
        for members in self._completed_sets(counted=False):
            try:
                frame_set = self._decode_set(members)
            except DecodeError:
                continue
            try:
                detect(frame_set)
            except Exception as err:
                raise self._detect_failed(frame_set.topic, frame_set.seq, err) from err
            break
        self._first_log = None
        forget = getattr(self.backend, 'forget_warmup', None)
        if callable(forget):
            forget()


def _set_warmup(replay: Replay, sets: int) -> int:
    """Warm-up sets of a set stream of ``sets`` sets: as a topic of that many frames has
    (``default_warmup``), or --warmup, at most ``sets - 1`` so that one set is measured."""
    wanted = replay.options.warmup
    if wanted is None:
        return default_warmup(sets)
    return max(0, min(wanted, sets - 1))
