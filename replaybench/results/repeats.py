"""Runs made of several passes (``replaybench run --repeat N``): the records of each pass, their
pooled throughput and series, and one time line for charts (the statistics of each pass that
``compare`` judges between repeats are ``replaybench.results.stats.repeat_statistics``).

A run with ``--repeat N`` replays every backend over the inputs N times, interleaved across
backends (A B A B ...), each pass with its own warm-up. frames.csv tells the passes apart by
its ``repeat`` column (0 to N - 1); the times of a frame (``release_s``, ``done_s``) count from
the start of its own pass. So a backend's series is its passes one after the other: latencies
are pooled, and the throughput of the run is its measured frames over the sum of the passes'
processing windows (the time between the passes, spent by the other backends, is no part of
it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    import numpy.typing as npt

    from replaybench.results.records import FrameRecord

    #: a pass's measured latencies (ms) and completion-to-completion times (s), as
    #: ``replaybench.results.intervals.Series`` holds them
    PassSeries = tuple[npt.NDArray[np.float64], npt.NDArray[np.float64] | None]

__all__ = [
    'by_repeat',
    'join_repeats',
    'one_timeline',
    'pooled_throughput',
    'repeat_count',
]


def by_repeat(records: Sequence[FrameRecord]) -> dict[int, list[FrameRecord]]:
    """The records of each pass, by repeat number (ascending), each in record order."""
    groups: dict[int, list[FrameRecord]] = {}
    for record in records:
        groups.setdefault(record.repeat, []).append(record)
    return dict(sorted(groups.items()))


def repeat_count(records: Sequence[FrameRecord]) -> int:
    """How many passes the records come from (1 for a run without ``--repeat``)."""
    return len({r.repeat for r in records}) or 1


def pooled_throughput(
    ordered: Sequence[FrameRecord],
    measured: Sequence[FrameRecord],
    throughput: Callable[[Sequence[FrameRecord], Sequence[FrameRecord]], float | None],
) -> float | None:
    """The throughput of one (backend, topic) over its passes: measured frames over the sum of
    each pass's window (``throughput`` gives one pass's frames per second); a single pass is
    ``throughput(ordered, measured)`` itself."""
    if len({r.repeat for r in ordered}) < 2:
        return throughput(ordered, measured)
    frames = 0
    window = 0.0
    for number, group in by_repeat(ordered).items():
        mine = [r for r in measured if r.repeat == number]
        if not mine:
            continue
        fps = throughput(group, mine)
        if fps is None or not fps > 0:
            return None
        frames += len(mine)
        window += len(mine) / fps
    return frames / window if window > 0 else None


def join_repeats(
    records: Sequence[FrameRecord], series: Callable[[Sequence[FrameRecord]], PassSeries]
) -> PassSeries | None:
    """The series of a run of several passes: each pass's ``series`` (latencies, intervals),
    one after the other; None for the records of a single pass (``series`` applies to them as
    they are)."""
    groups = by_repeat(records)
    if len(groups) < 2:
        return None
    parts = [series(group) for group in groups.values()]
    latency = np.concatenate([latency_ms for latency_ms, _ in parts])
    gaps = [intervals_s for _, intervals_s in parts if intervals_s is not None]
    intervals = np.concatenate(gaps) if len(gaps) == len(parts) else None
    return latency, intervals


def one_timeline(records: Sequence[FrameRecord]) -> list[FrameRecord]:
    """Records of one (backend, topic) in replay order on one time line, for charts: each pass's
    times (``release_s``, ``start_s``, ``done_s``) shifted to follow the end of the pass before
    it. Records of a single pass come back sorted by release time, unshifted."""
    groups = by_repeat(records)
    if len(groups) < 2:
        return sorted(records, key=lambda r: r.release_s)
    out: list[FrameRecord] = []
    offset = 0.0
    for group in groups.values():
        ordered = sorted(group, key=lambda r: r.release_s)
        end = 0.0
        for r in ordered:
            end = max(end, r.release_s, r.done_s or 0.0)
            out.append(
                r._replace(
                    release_s=r.release_s + offset,
                    start_s=None if r.start_s is None else r.start_s + offset,
                    done_s=None if r.done_s is None else r.done_s + offset,
                )
            )
        offset += end
    return out
