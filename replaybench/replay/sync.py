"""Synchronised frame sets (``--sync``): the frames of several topics grouped by header stamp.

Pure: it reads no file. ``parse_sync`` reads the ``--sync`` text, ``group_frames`` groups the
header stamps of each topic's frames into sets. Every set holds one frame of each topic, the
sets come in stamp order (in every topic, a later set holds a later frame), and a frame is in
at most one set; the frames that are in none are counted per topic (``Grouping.unpaired``).

``exact``: the frames that share a header stamp. A stamp that a topic holds twice (a driver
that repeats a stamp) pairs in order: the n-th frame of that stamp in each topic with the n-th
frame of it in the others; a topic holding fewer of them leaves the others' surplus unpaired.
(ROS ``message_filters.TimeSynchronizer`` keeps only the last of them, whichever arrives
last; replaying a recording, the order in the bag decides instead, so that the sets do not
depend on how the messages happened to interleave.)

``approx:SLOP_MS``: ROS ``message_filters``' ``ApproximateTime`` policy (the C++ one of ROS 1
and ROS 2, ``sync_policies/approximate_time.h``), its ``max_interval_duration`` the slop: a set
spans at most SLOP_MS between its earliest and its latest stamp (inclusive, as C++ drops a
candidate whose spread is *more* than the bound), and among the sets the frames allow it
chooses as the C++ policy does: take the fronts of the topics' queues as a candidate, pivot on
the topic of its latest stamp, and keep advancing the earliest frame while that gives a set of
smaller spread, until the candidate is provably the best one that contains the pivot's frame
(with the policy's default age penalty, 0.1: a later candidate must be better by that margin).
A recording gives the policy every frame at once and ends: the end is taken as a message at
infinity, which proves the pending candidate optimal, so the last set is published as a
running node would publish it on its next message. The queue is unbounded (the C++
``queue_size`` only drops messages a live node could not keep; a recording keeps them all),
and ``inter_message_lower_bound`` only lets a live node publish earlier, which changes no set.
Python's ``ApproximateTimeSynchronizer`` is not followed: it pairs greedily on each arrival
(the first combination within the slop of the newest message), so its sets depend on the order
of arrival across topics, and it keys each queue by stamp, losing repeated stamps.

Within a topic the frames are taken in stamp order (ties in replay order), as the policies
assume stamps that increase per topic. Deterministic: the same stamps give the same sets.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from replaybench.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['AGE_PENALTY', 'Grouping', 'StampSet', 'SyncSpec', 'group_frames', 'parse_sync']

#: ``message_filters`` ApproximateTime's default age penalty (ROS 1 and ROS 2, C++).
AGE_PENALTY = 0.1

_NS_PER_MS = 1_000_000
_APPROX = re.compile(r'approx:(?P<ms>[0-9]+(?:\.[0-9]*)?|\.[0-9]+)')

SyncMode = Literal['exact', 'approx']


@dataclass(frozen=True, slots=True)
class SyncSpec:
    """What ``--sync`` asks for: ``exact``, or ``approx`` within ``slop_ns``."""

    mode: SyncMode
    slop_ns: int = 0

    @property
    def slop_ms(self) -> float | None:
        """The slop in milliseconds; None for ``exact``."""
        return self.slop_ns / _NS_PER_MS if self.mode == 'approx' else None

    @property
    def policy(self) -> str:
        """One line naming the semantics (run.json's ``sync.policy``)."""
        if self.mode == 'exact':
            return 'exact: equal header stamps, a repeated stamp paired in order'
        return (
            'message_filters ApproximateTime (C++): max_interval_duration = slop, '
            f'age_penalty {AGE_PENALTY:g}, every frame queued'
        )

    @property
    def text(self) -> str:
        """The ``--sync`` text that gives this spec (``exact``, ``approx:5``)."""
        if self.mode == 'exact':
            return 'exact'
        return f'approx:{self.slop_ns / _NS_PER_MS:g}'


def parse_sync(text: object) -> SyncSpec:
    """The ``SyncSpec`` of a ``--sync`` text: ``exact`` or ``approx:SLOP_MS`` (a number of
    milliseconds >= 0); ``UsageError`` naming the option otherwise."""
    if not isinstance(text, str):
        msg = f'invalid --sync {text!r}: use exact or approx:SLOP_MS (e.g. approx:5)'
        raise UsageError(msg)
    given = text.strip()
    if given == 'exact':
        return SyncSpec('exact')
    found = _APPROX.fullmatch(given)
    if found is None:
        msg = f'invalid --sync {text!r}: use exact or approx:SLOP_MS (e.g. approx:5)'
        raise UsageError(msg)
    slop_ns = round(float(found['ms']) * _NS_PER_MS)
    return SyncSpec('approx', slop_ns)


@dataclass(frozen=True, slots=True)
class StampSet:
    """One set: per topic (in ``Grouping.topics``' order) the frame's index in that topic's
    stamps as given to ``group_frames``, and its stamp."""

    indices: tuple[int, ...]
    stamps: tuple[int, ...]

    @property
    def spread_ns(self) -> int:
        """Between the set's earliest and latest stamp."""
        return max(self.stamps) - min(self.stamps)


@dataclass(frozen=True, slots=True)
class Grouping:
    """The sets of ``topics``' frames, in stamp order, and how many frames each topic has."""

    topics: tuple[str, ...]
    sets: tuple[StampSet, ...]
    frames: tuple[int, ...]

    @property
    def unpaired(self) -> tuple[int, ...]:
        """Per topic: its frames that are in no set."""
        return tuple(n - len(self.sets) for n in self.frames)

    @property
    def spread_ns_max(self) -> int | None:
        """The largest spread of a set; None without sets."""
        return max((s.spread_ns for s in self.sets), default=None)


def group_frames(
    topics: Sequence[str],
    stamps: Sequence[Sequence[int]],
    spec: SyncSpec,
    *,
    age_penalty: float = AGE_PENALTY,
) -> Grouping:
    """The sets of the frames whose header stamps are ``stamps`` (per topic, in replay order)
    under ``spec`` (the module's docstring says how); ``age_penalty``: the approximate
    policy's."""
    if len(topics) != len(stamps):
        msg = f'{len(topics)} topics but {len(stamps)} lists of stamps'
        raise ValueError(msg)
    if not topics:
        return Grouping((), (), ())
    # per topic: (stamp, index), in stamp order; ties in replay order
    ordered = [sorted((s, i) for i, s in enumerate(per_topic)) for per_topic in stamps]
    if spec.mode == 'exact':
        sets = _exact(ordered)
    else:
        sets = _approximate(ordered, spec.slop_ns, age_penalty)
    return Grouping(tuple(topics), tuple(sets), tuple(len(s) for s in stamps))


def _frame_set(members: Sequence[tuple[int, int]]) -> StampSet:
    return StampSet(tuple(i for _, i in members), tuple(s for s, _ in members))


def _exact(ordered: list[list[tuple[int, int]]]) -> list[StampSet]:
    """The frames that share a stamp; repeats of a stamp paired in order."""
    by_stamp: list[dict[int, list[tuple[int, int]]]] = []
    for frames in ordered:
        table: dict[int, list[tuple[int, int]]] = {}
        for item in frames:
            table.setdefault(item[0], []).append(item)
        by_stamp.append(table)
    common = set(by_stamp[0]).intersection(*by_stamp[1:])
    sets: list[StampSet] = []
    for stamp in sorted(common):
        runs = [table[stamp] for table in by_stamp]
        sets.extend(
            _frame_set([run[k] for run in runs]) for k in range(min(len(run) for run in runs))
        )
    return sets


class _Approximate:
    """``message_filters`` ApproximateTime (C++) over queues that hold every frame at once."""

    def __init__(self, ordered: list[list[tuple[int, int]]], slop_ns: int, penalty: float):
        self.queues = [deque(frames) for frames in ordered]
        self.past: list[list[tuple[int, int]]] = [[] for _ in ordered]
        self.slop_ns = slop_ns
        self.penalty = penalty
        self.pivot: int | None = None
        self.pivot_time = 0
        self.candidate: list[tuple[int, int]] = []
        self.candidate_start = 0
        self.candidate_end = 0
        self.sets: list[StampSet] = []

    def _boundary(self, end: bool) -> tuple[int, int]:
        """(index, stamp) of the queue whose front is the earliest (``end``: the latest);
        ties as the C++ policy breaks them: the first topic for the start, the last for the
        end."""
        index, time = 0, self.queues[0][0][0]
        for i in range(1, len(self.queues)):
            stamp = self.queues[i][0][0]
            if (stamp < time) != end:
                index, time = i, stamp
        return index, time

    def _make_candidate(self, start_time: int, end_time: int) -> None:
        self.candidate = [q[0] for q in self.queues]
        for past in self.past:
            past.clear()  # a better candidate: the frames set aside for the last one return
        self.candidate_start, self.candidate_end = start_time, end_time

    def _publish(self) -> None:
        self.sets.append(_frame_set(self.candidate))
        self.candidate = []
        self.pivot = None
        for queue, past in zip(self.queues, self.past, strict=True):
            queue.extendleft(reversed(past))
            past.clear()
            queue.popleft()  # the candidate's frame of this topic

    def run(self) -> list[StampSet]:
        while True:
            if not all(self.queues):
                if self.pivot is None:
                    return self.sets  # the frames left pair with nothing
                self._publish()  # the recording's end: no later frame can better it
                continue
            end_index, end_time = self._boundary(end=True)
            start_index, start_time = self._boundary(end=False)
            if self.pivot is None:
                if end_time - start_time > self.slop_ns:
                    self.queues[start_index].popleft()  # pairs with nothing: unpaired
                    continue
                self._make_candidate(start_time, end_time)
                self.pivot, self.pivot_time = end_index, end_time
            elif (end_time - self.candidate_end) * (1 + self.penalty) < (
                start_time - self.candidate_start
            ):
                self._make_candidate(start_time, end_time)  # a better one; the same pivot
            self.past[start_index].append(self.queues[start_index].popleft())
            if start_index == self.pivot or (end_time - self.candidate_end) * (
                1 + self.penalty
            ) >= (self.pivot_time - self.candidate_start):
                self._publish()  # every candidate with the pivot's frame seen, or none better


def _approximate(
    ordered: list[list[tuple[int, int]]], slop_ns: int, penalty: float
) -> list[StampSet]:
    return _Approximate(ordered, slop_ns, penalty).run()
