"""Exact rank intervals for the ratio between two samples (Hodges–Lehmann / Moses).

For samples ``x`` (baseline, ``m`` values) and ``y`` (candidate, ``n`` values) of positive
numbers, the scale model says ``y`` is distributed as ``r · x``. Its logarithm is a shift
model, and the classic distribution-free interval for a shift (Moses 1953; Hodges & Lehmann
1963; Bauer 1972) applies: sort the ``m · n`` pairwise log ratios ``log y_j − log x_i``; the
Hodges–Lehmann estimate is their median, and ``[D_(k), D_(mn+1−k)]`` is a confidence interval
of level at least ``1 − 2 P(U < k)``, where ``U`` is the Mann–Whitney statistic, whose exact
null distribution (every arrangement of the ``m + n`` ranks equally likely) gives ``k``.

The interval excludes a ratio ``r0`` exactly when the exact two-sided Mann–Whitney test of
``y / r0`` against ``x`` rejects at ``1 − confidence``: ten frames all nine times slower than
ten others have ``P = 2 / C(20, 10) ≈ 1.1e-5``; three frames against three can never reach
5 % (``2 / C(6, 3) = 0.1``), so they get no interval.

The null distribution of ``U`` is the coefficient list of the Gaussian binomial
``[m + n choose m]_q = prod_{i=1..m} (1 − q^(n+i)) / (1 − q^i)``, built one factor at a time
(a multiplication and a running sum with stride ``i``), normalised at each step so it stays a
probability distribution in floating point: ``O(m² n)`` work, nothing sorted or enumerated.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = ['mann_whitney_null', 'moses_cut', 'ratio_interval', 'shift_interval']


@lru_cache(maxsize=256)
def _null(m: int, n: int) -> tuple[float, ...]:
    small, large = (m, n) if m <= n else (n, m)
    p = np.zeros(small * large + 1, dtype=np.float64)
    p[0] = 1.0
    for i in range(1, small + 1):
        top = i * large  # degree after this factor
        shifted = np.zeros_like(p)
        gap = large + i
        if gap <= top:
            shifted[gap : top + 1] = p[: top + 1 - gap]
        q = p - shifted
        # divide by (1 - q^i): r[k] = q[k] + r[k - i]
        for start in range(i):
            q[start : top + 1 : i] = np.cumsum(q[start : top + 1 : i])
        np.clip(q, 0.0, None, out=q)
        p = q / q.sum()
    return tuple(p.tolist())


def mann_whitney_null(m: int, n: int) -> npt.NDArray[np.float64]:
    """``P(U = u)`` for ``u = 0 .. m·n`` under the null hypothesis, for sample sizes m and n."""
    if m < 0 or n < 0:
        msg = f'sample sizes must be non-negative, not {m} and {n}'
        raise ValueError(msg)
    return np.asarray(_null(m, n), dtype=np.float64)


def moses_cut(m: int, n: int, confidence: float) -> int:
    """How many pairwise differences the interval drops at each end: the largest ``k`` with
    ``P(U < k) <= (1 − confidence) / 2``; 0 when no interval of that level exists."""
    if m < 1 or n < 1:
        return 0
    alpha = (1.0 - confidence) / 2.0
    cumulative = np.cumsum(mann_whitney_null(m, n))
    # P(U < k) = cumulative[k - 1]; a hair of slack for the floating-point sums
    return int(np.searchsorted(cumulative, alpha * (1.0 + 1e-9), side='right'))


def _valid(values: npt.ArrayLike, positive: bool) -> npt.NDArray[np.float64] | None:
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if not v.size or not np.all(np.isfinite(v)) or (positive and not np.all(v > 0)):
        return None
    return v


def shift_interval(
    baseline: npt.ArrayLike, candidate: npt.ArrayLike, confidence: float
) -> tuple[float | None, tuple[float, float] | None]:
    """Hodges–Lehmann shift ``candidate − baseline`` and its exact rank interval.

    ``(None, None)`` when a sample is empty or holds a value that is not finite;
    ``(estimate, None)`` when the samples are too small for an interval of that level.
    """
    x = _valid(baseline, positive=False)
    y = _valid(candidate, positive=False)
    if x is None or y is None:
        return None, None
    d = np.sort((y[None, :] - x[:, None]).reshape(-1))
    estimate = float(np.median(d))
    cut = moses_cut(x.size, y.size, confidence)
    if cut < 1:
        return estimate, None
    return estimate, (float(d[cut - 1]), float(d[d.size - cut]))


def ratio_interval(
    baseline: npt.ArrayLike, candidate: npt.ArrayLike, confidence: float
) -> tuple[float | None, tuple[float, float] | None]:
    """Hodges–Lehmann ratio ``candidate / baseline`` and its exact rank interval: the shift
    interval of the logarithms, mapped back.

    ``(None, None)`` when a sample is empty or holds a value that is not positive and finite;
    ``(estimate, None)`` when the samples are too small for an interval of that level.
    """
    x = _valid(baseline, positive=True)
    y = _valid(candidate, positive=True)
    if x is None or y is None:
        return None, None
    estimate, interval = shift_interval(np.log(x), np.log(y), confidence)
    if estimate is None:
        return None, None
    if interval is None:
        return math.exp(estimate), None
    return math.exp(estimate), (math.exp(interval[0]), math.exp(interval[1]))
