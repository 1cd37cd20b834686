"""Between repeats: the interval the gate judges when both runs were made with ``--repeat``,
and the caution that keeps a short, unstable single pass from failing the gate by itself.

Blocks of frames within one run cannot see that the machine was in another state during the
other run: a CPU hog that is on for most of one 0.3 s run and off for most of the next moves
every block of the first. Only the variation between runs shows that, and a run of ``--repeat
N`` holds N runs (passes), interleaved across its backends. So when the baseline and the
candidate each have at least ``MIN_REPEATS`` passes, each pass is summarised by the metric (its
median, p99, mean latency or throughput) and the passes are compared, as pyperf compares the
values of its worker processes:

- the change is the ratio of the geometric means of the passes' values (the difference of
  their means for absolute thresholds);
- its interval is Welch's t interval of the difference of the log values (of the values), with
  the Welch–Satterthwaite degrees of freedom.

What this can resolve with few passes: with 3 against 3, ``df`` lies between 2 and 4 and the
95 % quantile ``t`` between 4.30 and 2.78, so the interval's half-width on the log scale is
about ``t * cv * sqrt(2/3)`` for a between-pass coefficient of variation ``cv``. A ``+10 %``
gate passes an unchanged candidate only when ``cv`` stays below about 4 % (df 4) to 2.7 %
(df 2), and fails a +30 % change (``ln 1.3 - ln 1.1 = 0.167``) when ``cv`` stays below about
7 % (4.7 %); noisier passes leave the verdict inconclusive, never passed or failed by chance.
Rank methods cannot help here: 3 against 3 has no exact 95 % rank interval at all
(``2 / C(6, 3) = 0.1``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from replaybench.results.blocks import ChangeInterval
from replaybench.results.intervals import CV_LIMIT, drift
from replaybench.results.repeats import by_repeat
from replaybench.results.stats import repeat_statistics

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from replaybench.results.model import RepeatStats
    from replaybench.results.records import FrameRecord

__all__ = [
    'CAUTION_ADVICE',
    'MIN_REPEATS',
    'MIN_SINGLE_PASS_S',
    'PassValues',
    'pass_values',
    'repeat_change',
    'single_pass_caution',
    't_quantile',
]

#: Passes each run needs for the between-repeat interval (two give one degree of freedom).
MIN_REPEATS = 2
#: A single pass shorter than this (s of measured frames) with a stability warning cannot fail
#: a timing condition by itself (``single_pass_caution``): a phase of background load can fill
#: most of it. 3 s is the run length at which the gate's between-block interval was measured
#: under a CPU hog (docs/compare.md).
MIN_SINGLE_PASS_S = 3.0

#: What a row with a caution is told to do.
CAUTION_ADVICE = (
    'a timing condition cannot fail on it alone; make both runs with --repeat 3 (or longer '
    'runs) to decide'
)

#: The values of each pass of one (backend, topic), by metric.
PassValues = dict[str, 'npt.NDArray[np.float64]']

_FIELDS: dict[str, str] = {
    'median_ms': 'latency_ms_p50',
    'p99_ms': 'latency_ms_p99',
    'mean_ms': 'latency_ms_mean',
    'fps': 'throughput_fps',
}


def pass_values(records: Sequence[FrameRecord]) -> PassValues | None:
    """Per timing metric, the value of each pass of one (backend, topic)'s records; None for a
    run of a single pass."""
    if len(by_repeat(records)) < MIN_REPEATS:
        return None
    stats: tuple[RepeatStats, ...] = repeat_statistics(records)
    out: PassValues = {}
    for metric, name in _FIELDS.items():
        values = [getattr(s, name) for s in stats if s.measured]
        finite = [float(v) for v in values if v is not None and math.isfinite(v)]
        out[metric] = np.asarray(finite, dtype=np.float64)
    return out


def repeat_change(
    metric: str,
    baseline: PassValues | None,
    candidate: PassValues | None,
    confidence: float,
) -> ChangeInterval | None:
    """The between-repeat change of ``metric`` and its Welch interval; None unless both sides
    have ``MIN_REPEATS`` passes (the caller then compares blocks of frames)."""
    if baseline is None or candidate is None:
        return None
    x, y = baseline[metric], candidate[metric]
    if x.size < MIN_REPEATS or y.size < MIN_REPEATS:
        return None
    counts = (int(x.size), int(y.size))
    diff, diff_ci = _welch(x, y, confidence)
    if np.all(x > 0) and np.all(y > 0):
        log_diff, log_ci = _welch(np.log(x), np.log(y), confidence)
        ratio: float | None = math.exp(log_diff)
        ratio_ci: tuple[float, float] | None = (math.exp(log_ci[0]), math.exp(log_ci[1]))
    else:
        ratio = ratio_ci = None
    return ChangeInterval('between-repeat', counts, ratio, ratio_ci, diff, diff_ci)


def _welch(
    x: npt.NDArray[np.float64], y: npt.NDArray[np.float64], confidence: float
) -> tuple[float, tuple[float, float]]:
    """mean(y) - mean(x) and its Welch t interval."""
    d = float(y.mean() - x.mean())
    vx = float(x.var(ddof=1)) / x.size
    vy = float(y.var(ddof=1)) / y.size
    se = math.sqrt(vx + vy)
    if se == 0.0:
        return d, (d, d)
    df = (vx + vy) ** 2 / (vx**2 / (x.size - 1) + vy**2 / (y.size - 1))
    half = t_quantile(0.5 + confidence / 2, df) * se
    return d, (d - half, d + half)


def single_pass_caution(
    records: Sequence[FrameRecord], latency_ms: npt.NDArray[np.float64], fps: float | None
) -> str | None:
    """Why a row's timings cannot fail the gate by themselves, or None: a single pass whose
    measured frames took less than ``MIN_SINGLE_PASS_S`` and that carries a stability warning
    (latency CV above ``CV_LIMIT``, or drift between its halves)."""
    if len(by_repeat(records)) >= MIN_REPEATS or latency_ms.size == 0:
        return None
    if fps is None or not fps > 0:
        return None
    seconds = latency_ms.size / fps
    if seconds >= MIN_SINGLE_PASS_S:
        return None
    mean = float(latency_ms.mean())
    cv = float(latency_ms.std()) / mean if mean > 0 else 0.0
    reasons = []
    if cv > CV_LIMIT:
        reasons.append(f'latency CV {cv:.3f} > {CV_LIMIT:g}')
    drifted = drift(latency_ms)
    if drifted is not None and drifted.significant:
        reasons.append(f'latency drift {100 * (drifted.ratio - 1):+.0f} % between its halves')
    if not reasons:
        return None
    return (
        f'a single pass of {seconds:.2g} s (under {MIN_SINGLE_PASS_S:g} s) with '
        f'{" and ".join(reasons)}'
    )


# -- Student's t quantile (numpy has none; scipy is not a dependency) --------------------------


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 300):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-15:
            break
    return h


def _betainc(a: float, b: float, x: float) -> float:
    """The regularised incomplete beta function I_x(a, b)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    front = math.exp(
        math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    )
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


def _t_cdf(t: float, df: float) -> float:
    tail = 0.5 * _betainc(df / 2.0, 0.5, df / (df + t * t))
    return 1.0 - tail if t > 0 else tail


def t_quantile(p: float, df: float) -> float:
    """The ``p`` quantile of Student's t with ``df`` (> 0, not necessarily whole) degrees of
    freedom, to about 1e-10."""
    if not 0.0 < p < 1.0 or not df > 0:
        msg = f't_quantile needs 0 < p < 1 and df > 0, not p={p}, df={df}'
        raise ValueError(msg)
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    lo, hi = 0.0, 1.0
    while _t_cdf(hi, df) < p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _t_cdf(mid, df) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12 * max(1.0, hi):
            break
    return 0.5 * (lo + hi)
