"""95 % intervals and stability warnings of each (backend, topic) of a run.

One computation serves run.json, summary.csv, the report and ``replaybench compare RUN``:

* **Intervals** of the median (p50) and p99 latency and of the throughput (FPS): the
  circular block bootstrap of ``replaybench.results.bootstrap`` over the measured frames in
  replay order (latency and completion-to-completion times resampled jointly), 2000 resamples,
  central 95 % percentile interval. The generator of a (backend, topic) is seeded from the seed
  (0), the run's index among compared runs (0) and a CRC-32 of ``backend NUL topic``
  (``interval_rng``), so compare's interval of a run's own row is the same. None below
  ``MIN_FRAMES`` (20) measured frames.
* **Warnings**, in compare's wording where compare has the flag:

  - too few frames: fewer than ``MIN_FRAMES`` measured frames, so no interval; not said of a
    row whose measured frames carry no latency at all (a backend that is not timed, such as
    ``recorded``: its outputs' latency from the recording has its own note,
    ``replaybench.results.recorded_latency``);
  - unstable latency: coefficient of variation (population standard deviation / mean) above
    ``CV_LIMIT`` (0.1);
  - drift: the median latency of the second half of the measured frames differs from that of the
    first half by more than ``DRIFT_LIMIT`` (10 %) **and** the exact rank interval of that change
    (``replaybench.results.blocks.change_interval``, the gate's method: between blocks of
    consecutive frames from 20 frames a half, frame by frame below) excludes no change. Not judged
    below ``DRIFT_MIN_FRAMES`` (8) measured frames: 4 against 4 is the smallest split whose 95 %
    interval can exclude anything;
  - throttling, from the backend's resource summary (``replaybench.replay.resources``): the
    highest current CPU frequency of the process's CPUs, among samples in which the process kept at
    least half a core busy, fell by more than ``FREQ_DROP_LIMIT`` (10 %) from its highest to its
    lowest; the kernel counted thermal throttle events; or NVML reported a GPU clock throttle reason
    (power cap, thermal or hardware slowdown). Without cpufreq, thermal_throttle or NVML the
    corresponding check cannot be made and gives no warning. The resources cover the backend's whole
    replay (warm-up included) and every topic it replayed.
"""

from __future__ import annotations

import zlib
from dataclasses import replace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.results.blocks import change_interval
from replaybench.results.bootstrap import (
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    MIN_FRAMES,
    percentile_interval,
    replicates,
)
from replaybench.results.numbers import finite_number
from replaybench.results.records import written
from replaybench.results.repeats import join_repeats

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

    from replaybench.results.records import FrameRecord
    from replaybench.results.stats import Summary

__all__ = [
    'CV_LIMIT',
    'DRIFT_LIMIT',
    'DRIFT_MIN_FRAMES',
    'FREQ_DROP_LIMIT',
    'Drift',
    'Intervals',
    'Series',
    'drift',
    'interval_rng',
    'measured_series',
    'row_intervals',
    'stability_warnings',
    'throttle_warnings',
    'with_intervals',
]

#: A (backend, topic) whose latency coefficient of variation exceeds this is flagged unstable.
CV_LIMIT = 0.1
#: Second-half against first-half median latency: a larger relative change may be drift.
DRIFT_LIMIT = 0.10
#: Fewest measured frames for the drift check (4 a half).
DRIFT_MIN_FRAMES = 8
#: A larger relative fall of the busy CPU frequency is flagged as throttling.
FREQ_DROP_LIMIT = 0.10

Interval = tuple[float, float]


class Series(NamedTuple):
    """Measured latencies (ms) and completion-to-completion times (s), in replay order.

    ``intervals_s[i]`` is the time from the completion of the frame processed before measured
    frame ``i`` (warm-up included) to the completion of frame ``i``: they add up to the
    throughput window of summary.csv. None when a completion time is missing.
    """

    latency_ms: npt.NDArray[np.float64]
    intervals_s: npt.NDArray[np.float64] | None


class Intervals(NamedTuple):
    """95 % intervals of one (backend, topic); None each below ``MIN_FRAMES`` frames."""

    p50: Interval | None
    p99: Interval | None
    fps: Interval | None
    #: bootstrap block length in frames (None without a bootstrap)
    block: int | None


class Drift(NamedTuple):
    """Second half of the measured frames against the first half."""

    first_ms: float
    second_ms: float
    #: median(second half) / median(first half)
    ratio: float
    #: exact rank interval of the typical change (None when the halves are too small)
    ratio_ci: Interval | None
    method: str

    @property
    def significant(self) -> bool:
        """More than ``DRIFT_LIMIT`` apart and the interval excludes no change."""
        if self.ratio_ci is None or not abs(self.ratio - 1.0) > DRIFT_LIMIT:
            return False
        lo, hi = self.ratio_ci
        return not lo <= 1.0 <= hi


def measured_series(records: Sequence[FrameRecord]) -> Series:
    """The series of one (backend, topic)'s records that the intervals resample.

    Values are taken as frames.csv writes them (latency to 0.1 µs, times to 1 µs), so the
    records of a run in memory and the same records read back from its frames.csv give the same
    series, and run.json the same intervals as ``replaybench compare`` of the run folder.
    """
    if (passes := join_repeats(records, measured_series)) is not None:
        return Series(*passes)  # --repeat: each pass's series, one after the other
    # stable, as stats.py; by the release time frames.csv holds (ties keep the record order)
    ordered = sorted(records, key=lambda r: written(r.release_s, 'release_s'))
    measured = [
        r for r in ordered if r.status == 'ok' and not r.warmup and r.latency_ms is not None
    ]
    latency = np.asarray(
        [written(r.latency_ms, 'latency_ms') for r in measured if r.latency_ms is not None],
        dtype=np.float64,
    )
    if not measured or any(r.done_s is None for r in measured):
        return Series(latency, None)
    start = measured[0].start_s
    previous = None
    for record in ordered:
        if record is measured[0]:
            break
        if record.status == 'ok':
            previous = record
    if previous is not None and previous.done_s is not None:
        start = previous.done_s
    if start is None:
        return Series(latency, None)
    done = np.asarray(
        [written(t, 'done_s') for t in [start] + [r.done_s for r in measured] if t is not None],
        dtype=np.float64,
    )
    return Series(latency, np.diff(done))


def interval_rng(seed: int, run: int, backend: str, topic: str) -> np.random.Generator:
    """The bootstrap generator of one (run, backend, topic); ``run`` is the run's index among
    the compared runs (0 for a run on its own)."""
    key = zlib.crc32(f'{backend}\0{topic}'.encode())
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(run, key)))


def row_intervals(
    backend: str,
    topic: str,
    series: Series,
    *,
    seed: int = 0,
    run: int = 0,
    n_boot: int = DEFAULT_RESAMPLES,
    confidence: float = CONFIDENCE,
    points: tuple[float | None, float | None, float | None] = (None, None, None),
) -> Intervals:
    """The 95 % intervals of p50, p99 and FPS of one (backend, topic); ``points``, the
    reported (p50, p99, FPS), each lies in its interval (``percentile_interval``)."""
    reps = replicates(
        series.latency_ms,
        series.intervals_s,
        n_boot=n_boot,
        rng=interval_rng(seed, run, backend, topic),
    )
    if reps is None:
        return Intervals(None, None, None, None)
    p50, p99, fps = points
    return Intervals(
        percentile_interval(reps.p50, confidence, point=p50),
        percentile_interval(reps.p99, confidence, point=p99),
        percentile_interval(reps.fps, confidence, point=fps) if reps.fps is not None else None,
        reps.block,
    )


def drift(latency_ms: npt.ArrayLike, confidence: float = CONFIDENCE) -> Drift | None:
    """The second half of a latency series against its first half; None below
    ``DRIFT_MIN_FRAMES`` values or when a median is not positive."""
    lat = np.asarray(latency_ms, dtype=np.float64).reshape(-1)
    if lat.size < DRIFT_MIN_FRAMES or not bool(np.all(np.isfinite(lat))):
        return None
    half = lat.size // 2
    first, second = lat[:half], lat[half:]
    a = float(np.percentile(first, 50, method='linear'))
    b = float(np.percentile(second, 50, method='linear'))
    if not a > 0 or not b > 0:
        return None
    found = change_interval('median_ms', first, second, confidence=confidence)
    return Drift(a, b, b / a, found.ratio_ci, found.method)


def throttle_warnings(resources: Mapping[str, Any] | None) -> list[str]:
    """Throttling seen in a backend's resource summary (``ResourceSampler.summary()``)."""
    if not resources:
        return []
    out = []
    high, low = (
        finite_number(resources.get('cpu_mhz_max')),
        finite_number(resources.get('cpu_mhz_min')),
    )
    if high is not None and low is not None and high > 0:
        fall = 1.0 - low / high
        if fall > FREQ_DROP_LIMIT:
            out.append(
                f'CPU throttling: busy CPU frequency fell {100 * fall:.0f} % '
                f'({high:.0f} to {low:.0f} MHz) > {100 * FREQ_DROP_LIMIT:g} %'
            )
    events = resources.get('cpu_throttle_events')
    if isinstance(events, int) and not isinstance(events, bool) and events > 0:
        out.append(f'CPU throttling: {events} thermal throttle event(s) counted by the kernel')
    reasons = resources.get('gpu_throttle_reasons')
    if isinstance(reasons, list) and reasons:
        out.append('GPU throttling: ' + ', '.join(str(r) for r in reasons))
    return out


def stability_warnings(
    summary: Summary,
    series: Series,
    drifted: Drift | None = None,
    resources: Mapping[str, Any] | None = None,
) -> list[str]:
    """The warnings of one (backend, topic), in a fixed order (frames, CV, drift, throttling
    seen in its backend's ``resources``)."""
    out = []
    n = int(series.latency_ms.size)
    not_timed = n == 0 and summary.measured > 0  # frames measured, none with a latency
    if n < MIN_FRAMES and not not_timed:
        out.append(f'{n} measured frames: fewer than {MIN_FRAMES}, no 95 % interval')
    mean, std = summary.latency_ms_mean, summary.latency_ms_std
    cv = std / mean if mean and std is not None and mean > 0 else None
    if cv is not None and cv > CV_LIMIT:
        out.append(f'unstable latency: CV {cv:.3f} > {CV_LIMIT:g}')
    if drifted is not None and drifted.significant and drifted.ratio_ci is not None:
        lo, hi = drifted.ratio_ci
        out.append(
            f'latency drift: second-half median {drifted.second_ms:.3g} ms vs first-half '
            f'{drifted.first_ms:.3g} ms, {100 * (drifted.ratio - 1):+.0f} % (more than '
            f'{100 * DRIFT_LIMIT:g} %; 95 % interval of the ratio {lo:.3f} to {hi:.3f})'
        )
    out += throttle_warnings(resources)
    return out


def with_intervals(
    summaries: Sequence[Summary],
    records: Sequence[FrameRecord],
    *,
    seed: int = 0,
    resources: Mapping[str, Mapping[str, Any]] | None = None,
) -> list[Summary]:
    """``summaries`` with their intervals and warnings filled in from ``records`` (the frame
    records they were computed from) and, for throttling, each backend's resource summary
    (``resources``, by backend label)."""
    groups: dict[tuple[str, str], list[FrameRecord]] = {}
    for record in records:
        groups.setdefault((record.backend, record.topic), []).append(record)
    out = []
    for s in summaries:
        series = measured_series(groups.get((s.backend, s.topic), []))
        found = row_intervals(
            s.backend,
            s.topic,
            series,
            seed=seed,
            points=(s.latency_ms_p50, s.latency_ms_p99, s.throughput_fps),
        )
        p50, p99, fps = found.p50, found.p99, found.fps
        out.append(
            replace(
                s,
                latency_ms_p50_ci_low=p50[0] if p50 else None,
                latency_ms_p50_ci_high=p50[1] if p50 else None,
                latency_ms_p99_ci_low=p99[0] if p99 else None,
                latency_ms_p99_ci_high=p99[1] if p99 else None,
                throughput_fps_ci_low=fps[0] if fps else None,
                throughput_fps_ci_high=fps[1] if fps else None,
                warnings=tuple(
                    stability_warnings(
                        s,
                        series,
                        drift(series.latency_ms),
                        (resources or {}).get(s.backend),
                    )
                ),
            )
        )
    return out
