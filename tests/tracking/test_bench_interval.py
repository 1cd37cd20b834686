"""The interval benchmarks/bench_tracking.py reports the trackers' added latency with: the
distribution-free 95 % interval of a median (order statistics), checked against its
definition (the binomial coverage) and against known order statistics."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

REPO = str(Path(__file__).resolve().parents[2])
if REPO not in sys.path:  # the benchmarks package, however pytest was started
    sys.path.insert(0, REPO)

from benchmarks.bench_tracking import median_interval  # noqa: E402 - after the path above


def _coverage(n: int, k: int) -> float:
    """1 - 2 P(X <= k - 1), X ~ Binomial(n, 1/2): the coverage of [x_(k), x_(n+1-k)]."""
    return 1 - 2 * sum(math.comb(n, j) for j in range(k)) / float(2**n)


@pytest.mark.parametrize('n', range(6, 41))
def test_the_interval_covers_95_percent_and_is_the_narrowest_that_does(n: int) -> None:
    values = [float(v) for v in range(1, n + 1)]  # x_(j) = j
    low, high = median_interval(list(reversed(values)))
    k = int(low)
    assert high == n + 1 - k
    assert _coverage(n, k) >= 0.95
    assert _coverage(n, k + 1) < 0.95  # one order statistic in from each side no longer covers


def test_known_order_statistics_for_15_and_16_values() -> None:
    assert median_interval([float(v) for v in range(1, 16)]) == (4.0, 12.0)
    assert median_interval([float(v) for v in range(1, 17)]) == (4.0, 13.0)


def test_too_few_values_for_95_percent_give_the_extremes() -> None:
    assert median_interval([3.0, 1.0, 2.0, 5.0, 4.0]) == (1.0, 5.0)
    assert median_interval([2.0]) == (2.0, 2.0)
