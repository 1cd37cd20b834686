"""Circular block bootstrap of per-frame series (latency, inter-completion interval).

Per-frame latencies are autocorrelated (thermal state, caches, background load drift slowly),
so frames are not resampled one by one but in blocks of consecutive frames in replay order.
A resample of a series of ``n`` frames joins ``ceil(n / L)`` blocks of ``L`` consecutive frames
whose starts are drawn uniformly from the ``n`` positions, wrapping around the end (circular
block bootstrap, Politis & Romano 1992), cut to ``n`` frames.

Block length: ``L = max(ceil(n ** (1/3)), L_PW)``. ``n ** (1/3)`` is the order of the block
length that minimises the error of block-bootstrap variance and distribution estimates (Hall,
Horowitz & Jing 1995); its constant depends on how long the series remembers. ``L_PW`` is the
data-driven estimate of Politis & White (2004, corrected by Patton, Politis & White 2009) from
the series' autocorrelation: it lengthens the blocks of slowly drifting series, for which
``ceil(n ** (1/3))`` alone gives too narrow intervals (simulated AR(1), rho 0.9, 600 frames:
80 % coverage of nominal 95 % with ``n ** (1/3)`` alone, 89 % with the maximum).

Replicates of a quantile are exact (the same value ``numpy.percentile(..., method='linear')``
gives on the explicit resample): each resample is counted into a histogram over the ranks of
the original values, so no resample is ever sorted. Sums use per-block sums. Nothing here
loops over frames in Python.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

if TYPE_CHECKING:
    from collections.abc import Sequence
    from typing import TypeAlias

    import numpy.typing as npt

    FloatArray: TypeAlias = npt.NDArray[np.float64]
    IntArray: TypeAlias = npt.NDArray[np.intp]

__all__ = [
    'CONFIDENCE',
    'DEFAULT_RESAMPLES',
    'MIN_FRAMES',
    'Replicates',
    'block_length',
    'block_starts',
    'block_sums',
    'percentile_interval',
    'politis_white_length',
    'quantile_replicates',
    'ratio_ci',
    'replicates',
]

#: Level of every confidence interval.
CONFIDENCE = 0.95

#: Bootstrap resamples per series.
DEFAULT_RESAMPLES = 2000

#: Fewer measured frames than this: no bootstrap (and no confidence interval).
MIN_FRAMES = 20

# Series up to this many frames are counted many resamples at a time (about this many values
# per batch); longer ones one resample at a time, which keeps the counts in cache.
_BATCH_MAX_FRAMES = 4096
_BATCH_ELEMENTS = 1 << 16


def block_length(n: int) -> int:
    """``ceil(n ** (1/3))`` computed exactly in integers, between 1 and ``n``."""
    if n <= 1:
        return 1
    length = max(1, round(math.pow(n, 1.0 / 3.0)))
    while length * length * length < n:
        length += 1
    while length > 1 and (length - 1) * (length - 1) * (length - 1) >= n:
        length -= 1
    return min(length, n)


def _autocovariances(values: FloatArray, lags: int) -> FloatArray:
    """Sample autocovariances (divisor n) for lags 0..lags, via one FFT."""
    n = values.size
    centred = values - values.mean()
    size = 1 << int(2 * n - 1).bit_length()
    spectrum = np.fft.rfft(centred, size)
    acov: FloatArray = np.fft.irfft(spectrum * np.conj(spectrum), size)[: lags + 1] / n
    return acov


def _flat_top(t: FloatArray) -> FloatArray:
    a = np.abs(t)
    weights: FloatArray = np.where(a <= 0.5, 1.0, np.where(a <= 1.0, 2.0 * (1.0 - a), 0.0))
    return weights


def politis_white_length(values: npt.ArrayLike) -> int:
    """Data-driven circular block length (Politis & White 2004, Patton et al. 2009 correction).

    Estimates the block length that minimises the error of the block-bootstrap variance of the
    mean from the autocorrelation of the series: longer blocks for longer memory, 1 for a
    series without significant autocorrelation. Capped at ``min(3 sqrt(n), n / 3)``.
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    n = v.size
    if n < 9:
        return 1
    runs = max(5, math.ceil(math.sqrt(math.log10(n))))
    max_lag = min(n - 1, math.ceil(math.sqrt(n)) + runs)
    cap = max(1, math.ceil(min(3.0 * math.sqrt(n), n / 3.0)))
    acov = _autocovariances(v, max_lag)
    if not acov[0] > 0:
        return 1
    rho = np.abs(acov[1:] / acov[0])  # lags 1..max_lag
    limit = 2.0 * math.sqrt(math.log10(n) / n)
    significant = rho >= limit
    m_hat = None
    for m in range(max_lag - runs + 1):
        # lags m+1 .. m+runs all insignificant
        if not significant[m : m + runs].any():
            m_hat = m
            break
    if m_hat is None:
        found = np.flatnonzero(significant)
        m_hat = int(found[-1]) + 1 if found.size else 0
    big_m = min(2 * m_hat, max_lag)
    if big_m == 0:
        return 1
    k = np.arange(-big_m, big_m + 1)
    weights = _flat_top(k / big_m)
    gamma = acov[np.abs(k)]
    g = float(np.sum(weights * np.abs(k) * gamma))
    spectral = float(np.sum(weights * gamma))
    d_cb = 4.0 / 3.0 * spectral * spectral
    if not d_cb > 0:
        return cap
    best = (2.0 * g * g / d_cb) ** (1.0 / 3.0) * n ** (1.0 / 3.0)
    return int(min(cap, max(1, math.ceil(best))))


def block_starts(n: int, n_boot: int, block: int, rng: np.random.Generator) -> IntArray:
    """Uniform block starts, shape ``(n_boot, ceil(n / block))``; the last block is cut short."""
    blocks = -(-n // block)
    starts: IntArray = rng.integers(0, n, size=(n_boot, blocks), dtype=np.intp)
    return starts


def _last_length(n: int, block: int) -> int:
    return n - (-(-n // block) - 1) * block


def block_sums(values: npt.ArrayLike, starts: IntArray, block: int) -> FloatArray:
    """Sum of each resample described by ``starts`` (shape ``(n_boot,)``)."""
    v = np.asarray(values, dtype=np.float64)
    n = v.size
    wrapped = np.concatenate((v, v[: block - 1]))
    full = sliding_window_view(wrapped, block)[:n].sum(axis=1)
    last = _last_length(n, block)
    tail = full if last == block else sliding_window_view(wrapped, last)[:n].sum(axis=1)
    sums: FloatArray = full[starts[:, :-1]].sum(axis=1) + tail[starts[:, -1]]
    return sums


def quantile_replicates(
    values: npt.ArrayLike, starts: IntArray, block: int, qs: Sequence[float]
) -> FloatArray:
    """Quantiles ``qs`` (0..1, linear interpolation) of each resample: shape ``(n_boot, len(qs))``.

    Exact: equal to ``numpy.percentile(resample, 100 * qs, method='linear')``.
    """
    v = np.asarray(values, dtype=np.float64)
    n = v.size
    order = np.argsort(v, kind='stable')
    ordered = v[order]
    rank = np.empty(n, dtype=np.intp)
    rank[order] = np.arange(n, dtype=np.intp)
    windows = sliding_window_view(np.concatenate((rank, rank[: block - 1])), block)
    h = np.asarray(qs, dtype=np.float64) * (n - 1)
    lo = np.floor(h).astype(np.intp)
    hi = np.minimum(lo + 1, n - 1)
    frac = h - lo
    targets = np.concatenate((lo, hi))
    picked = np.empty((starts.shape[0], targets.size), dtype=np.float64)
    # cumulative[j] = how many resampled values have rank <= j; the value of rank t in the
    # sorted resample is ordered[first j with cumulative[j] > t].
    if n <= _BATCH_MAX_FRAMES:
        rows = max(1, _BATCH_ELEMENTS // n)
        for first in range(0, starts.shape[0], rows):
            chunk = starts[first : first + rows]
            m = chunk.shape[0]
            # Offsetting row r by r * n makes the flattened cumulative counts non-decreasing,
            # so one searchsorted serves every row of the chunk.
            offset = (np.arange(m, dtype=np.intp) * n)[:, None]
            ranks = windows[chunk].reshape(m, -1)[:, :n] + offset
            counts = np.bincount(ranks.reshape(-1), minlength=m * n).reshape(m, n)
            cumulative = np.cumsum(counts, axis=1) + offset
            found = np.searchsorted(
                cumulative.reshape(-1), (targets[None, :] + offset).reshape(-1), side='right'
            )
            picked[first : first + m] = ordered[found.reshape(m, -1) - offset]
    else:
        for i, row in enumerate(starts):
            ranks = windows[row].reshape(-1)[:n]
            cumulative = np.cumsum(np.bincount(ranks, minlength=n))
            picked[i] = ordered[cumulative.searchsorted(targets, side='right')]
    a, b = picked[:, : lo.size], picked[:, lo.size :]
    result: FloatArray = a + (b - a) * frac
    return result


class Replicates(NamedTuple):
    """Bootstrap replicates of one series' statistics (each of shape ``(n_boot,)``)."""

    n: int
    block: int
    mean: FloatArray
    p50: FloatArray
    p99: FloatArray
    fps: FloatArray | None


def replicates(
    latency_ms: npt.ArrayLike,
    intervals_s: npt.ArrayLike | None,
    *,
    n_boot: int = DEFAULT_RESAMPLES,
    rng: np.random.Generator,
    block: int | None = None,
) -> Replicates | None:
    """Replicates of mean, median and p99 latency and of the throughput of one series.

    ``intervals_s[i]`` is the time from the completion of the frame before frame ``i`` to the
    completion of frame ``i`` (so ``n / sum(intervals)`` is the throughput); frames are resampled
    jointly, the same blocks for both series. None when the series has fewer than
    ``MIN_FRAMES`` frames.
    """
    lat = np.asarray(latency_ms, dtype=np.float64).reshape(-1)
    n = lat.size
    if n < MIN_FRAMES or n_boot < 1:
        return None
    if block is None:
        size = max(block_length(n), politis_white_length(lat))
    else:
        size = max(1, min(int(block), n))
    starts = block_starts(n, n_boot, size, rng)
    quantiles = quantile_replicates(lat, starts, size, (0.5, 0.99))
    fps = None
    if intervals_s is not None:
        iv = np.asarray(intervals_s, dtype=np.float64).reshape(-1)
        if iv.size == n and bool(np.all(np.isfinite(iv))):
            with np.errstate(divide='ignore', invalid='ignore'):
                fps = n / block_sums(iv, starts, size)
    return Replicates(
        n=n,
        block=size,
        mean=block_sums(lat, starts, size) / n,
        p50=quantiles[:, 0],
        p99=quantiles[:, 1],
        fps=fps,
    )


def percentile_interval(
    samples: npt.ArrayLike, confidence: float = CONFIDENCE, *, point: float | None = None
) -> tuple[float, float] | None:
    """The central ``confidence`` percentile interval of bootstrap replicates.

    ``point``: the estimate the interval is reported around. The percentile interval of an
    extreme quantile of few frames can lie beside it (the p99 of 40 frames rests on the two
    slowest, and most resamples hold the slowest); it is then extended to the estimate, so an
    interval never excludes its own value and only ever grows.
    None when there are no replicates or any of them is not finite (e.g. a division by zero).
    """
    s = np.asarray(samples, dtype=np.float64).reshape(-1)
    if not s.size or not bool(np.all(np.isfinite(s))):
        return None
    alpha = (1.0 - confidence) / 2.0
    lo, hi = (float(v) for v in np.quantile(s, [alpha, 1.0 - alpha], method='linear'))
    if point is not None and math.isfinite(point):
        lo, hi = min(lo, point), max(hi, point)
    return lo, hi


def _point(values: FloatArray, statistic: str) -> float:
    if statistic == 'mean':
        return float(np.mean(values))
    return float(np.percentile(values, 50 if statistic == 'p50' else 99))


def ratio_ci(
    baseline: npt.ArrayLike,
    candidate: npt.ArrayLike,
    statistic: str = 'p50',
    *,
    n_boot: int = DEFAULT_RESAMPLES,
    seed: int = 0,
    confidence: float = CONFIDENCE,
) -> tuple[float, tuple[float, float] | None]:
    """Point estimate and bootstrap CI of ``statistic(candidate) / statistic(baseline)``.

    ``statistic`` is ``'p50'``, ``'p99'`` or ``'mean'``. The two series are resampled
    independently (blocks from one generator seeded with ``seed``: baseline first).
    """
    if statistic not in {'p50', 'p99', 'mean'}:
        msg = f'unknown statistic {statistic!r} (p50, p99 or mean)'
        raise ValueError(msg)
    b = np.asarray(baseline, dtype=np.float64).reshape(-1)
    c = np.asarray(candidate, dtype=np.float64).reshape(-1)
    estimate = _point(c, statistic) / _point(b, statistic) if b.size and c.size else math.nan
    rng = np.random.default_rng(seed)
    rb = replicates(b, None, n_boot=n_boot, rng=rng)
    rc = replicates(c, None, n_boot=n_boot, rng=rng)
    if rb is None or rc is None:
        return estimate, None
    with np.errstate(divide='ignore', invalid='ignore'):
        ratios = getattr(rc, statistic) / getattr(rb, statistic)
    return estimate, percentile_interval(ratios, confidence)
