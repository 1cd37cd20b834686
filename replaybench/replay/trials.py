"""A peak search's trials: the verdict of one trial, and the peak the trials support."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from replaybench.results.model import PeakTrial

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.records import FrameRecord

__all__ = ['Trial', 'peak_rule', 'trial_row', 'trial_verdict']


class Trial(NamedTuple):
    """One fixed-rate run of the sweep.

    ``frames`` and ``dropped`` count the frames released from the end of the warm-up on (see
    ``trial_verdict``); ``p99_ms`` is over the measured frames of every topic together;
    ``run_dir`` is the trial's run folder relative to the sweep's ``out_dir``; ``attempt`` is
    1 for the first trial at a rate, 2 and up for the trials that confirm it.
    """

    rate_hz: float
    frames: int
    dropped: int
    drop_fraction: float
    p99_ms: float | None
    ok: bool
    run_dir: str
    attempt: int = 1
    #: ``peak --cameras``: the copies of the bag's camera set the trial replayed (None for a
    #: trial of the rate search)
    copies: int | None = None


def trial_verdict(
    records: Sequence[FrameRecord], *, max_drop: float, p99_bound_ms: float | None
) -> tuple[int, int, float | None, bool]:
    """``(frames, dropped, p99_ms, ok)`` of one trial's frames.csv rows.

    Per topic, frames released before the first measured (non-warm-up) frame are left out: a
    backend's first calls (model loading, allocation, JIT) would otherwise count as drops. A
    trial is ok when it measured at least one frame, ``dropped / frames <= max_drop`` and, with
    a bound, the p99 latency of the measured frames is at most ``p99_bound_ms``.
    """
    by_topic: dict[str, list[FrameRecord]] = {}
    for record in records:
        by_topic.setdefault(record.topic, []).append(record)
    frames = dropped = 0
    latencies: list[float] = []
    for rows in by_topic.values():
        measured = [r for r in rows if r.status == 'ok' and not r.warmup]
        latencies += [r.latency_ms for r in measured if r.latency_ms is not None]
        start = min((r.release_s for r in measured), default=None)
        counted = rows if start is None else [r for r in rows if r.release_s >= start]
        frames += len(counted)
        dropped += sum(1 for r in counted if r.status == 'dropped')
    p99 = float(np.percentile(latencies, 99, method='linear')) if latencies else None
    ok = bool(latencies) and frames > 0 and dropped / frames <= max_drop
    if ok and p99_bound_ms is not None:
        ok = p99 is not None and p99 <= p99_bound_ms
    return frames, dropped, p99, ok


def peak_rule(
    trials: Sequence[Trial], confirm_trials: int, *, by: str = 'rate_hz'
) -> tuple[float | None, bool]:
    """The peak the trials support, and whether it is confirmed.

    The peak is the highest rate that passed every one of its trials and lies below every rate
    that failed a trial; it is confirmed when it passed at least ``confirm_trials`` trials.
    ``(None, False)`` when no rate qualifies. ``by='copies'``: the same rule over the copies of
    a camera set (``peak --cameras``) instead of the rate.
    """
    failed = [getattr(t, by) for t in trials if not t.ok]
    lowest_failed = min(failed, default=None)
    passed: dict[float, int] = {}
    for t in trials:
        if t.ok:
            passed[getattr(t, by)] = passed.get(getattr(t, by), 0) + 1
    candidates = [
        rate
        for rate in passed
        if rate not in failed and (lowest_failed is None or rate < lowest_failed)
    ]
    if not candidates:
        return None, False
    best = max(candidates)
    return best, passed[best] >= confirm_trials


def trial_row(trial: Trial) -> PeakTrial:
    """A trial as peak.json holds it (a p99 that is not finite is null)."""
    p99 = trial.p99_ms if trial.p99_ms is not None and math.isfinite(trial.p99_ms) else None
    return PeakTrial(**{**trial._asdict(), 'p99_ms': p99})
