from __future__ import annotations

import time

import numpy as np
import pytest

from replaybench.results.bootstrap import (
    MIN_FRAMES,
    block_length,
    block_starts,
    block_sums,
    percentile_interval,
    politis_white_length,
    quantile_replicates,
    ratio_ci,
    replicates,
)


@pytest.mark.parametrize(
    ('n', 'expected'),
    [(1, 1), (2, 2), (8, 2), (9, 3), (27, 3), (28, 4), (1000, 10), (1001, 11), (10_000, 22)],
)
def test_block_length_is_the_ceiling_of_the_cube_root(n: int, expected: int) -> None:
    assert block_length(n) == expected


def _ar1(n: int, rho: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = np.empty(n)
    x[0] = rng.normal()
    for i in range(1, n):
        x[i] = rho * x[i - 1] + np.sqrt(1 - rho * rho) * rng.normal()
    return x


def test_data_driven_block_length_follows_the_memory_of_the_series() -> None:
    # AR(1) with rho = 0.9: the optimal circular block length is
    # (2 G^2 / D)^(1/3) n^(1/3) = 5.12 * n^(1/3), about 110 frames for n = 10 000.
    assert 70 <= politis_white_length(_ar1(10_000, 0.9, seed=1)) <= 160
    assert politis_white_length(_ar1(10_000, 0.0, seed=1)) <= 2
    assert politis_white_length(np.ones(100)) == 1
    assert politis_white_length([1.0, 2.0, 3.0]) == 1
    # the bootstrap uses ceil(n^(1/3)) at least, longer blocks when the series needs them
    iid = replicates(_ar1(1000, 0.0, seed=2) + 10, None, n_boot=10, rng=np.random.default_rng(0))
    slow = replicates(_ar1(1000, 0.95, seed=2) + 10, None, n_boot=10, rng=np.random.default_rng(0))
    assert iid is not None
    assert slow is not None
    assert iid.block == block_length(1000) == 10
    assert slow.block > 30


def _explicit_resamples(n: int, starts: np.ndarray, block: int) -> np.ndarray:
    """The resamples spelled out: blocks of consecutive indices, wrapping, cut to n."""
    offsets = np.arange(block)
    return ((starts[:, :, None] + offsets) % n).reshape(starts.shape[0], -1)[:, :n]


@pytest.mark.parametrize('n', [20, 23, 64, 101, 997, 5003])
def test_quantile_and_sum_replicates_equal_numpy_on_the_explicit_resamples(n: int) -> None:
    rng = np.random.default_rng(n)
    values = np.round(rng.gamma(3.0, 1.0, n), 1)  # rounded: many ties
    block = block_length(n)
    starts = block_starts(n, 40, block, np.random.default_rng(1))
    index = _explicit_resamples(n, starts, block)
    qs = (0.0, 0.37, 0.5, 0.99, 1.0)
    expected = np.percentile(values[index], [100 * q for q in qs], axis=1, method='linear').T
    np.testing.assert_allclose(quantile_replicates(values, starts, block, qs), expected, rtol=1e-12)
    np.testing.assert_allclose(block_sums(values, starts, block), values[index].sum(axis=1))


def test_resamples_keep_runs_of_consecutive_frames_together() -> None:
    # A series that is 1 for the first half and 1000 for the second: a block bootstrap moves
    # whole blocks, so the resampled median is always one of the two levels.
    series = np.r_[np.ones(500), np.full(500, 1000.0)]
    reps = replicates(series, None, n_boot=300, rng=np.random.default_rng(3))
    assert reps is not None
    assert reps.block >= 10
    assert set(np.unique(reps.p50)) <= {1.0, 1000.0, 500.5}
    assert 0.3 < np.mean(reps.p50 == 1.0) < 0.7


def test_same_seed_gives_the_same_interval_and_another_seed_another() -> None:
    base = np.random.default_rng(0).lognormal(1.0, 0.2, 500)
    cand = np.random.default_rng(1).lognormal(1.05, 0.2, 500)
    first = ratio_ci(base, cand, 'p50', n_boot=500, seed=7)
    again = ratio_ci(base, cand, 'p50', n_boot=500, seed=7)
    other = ratio_ci(base, cand, 'p50', n_boot=500, seed=8)
    assert first == again
    assert first[1] is not None
    assert other[1] is not None
    assert first[1] != other[1]
    assert first[0] == other[0]  # the point estimate does not depend on the seed


def test_interval_covers_the_true_median_ratio_about_95_percent_of_the_time() -> None:
    rng = np.random.default_rng(2024)
    true_ratio = 12.0 / 10.0  # medians of N(10, 1) and N(12, 1.5)
    covered = 0
    cases = 200
    for case in range(cases):
        base = rng.normal(10.0, 1.0, 150)
        cand = rng.normal(12.0, 1.5, 150)
        _, ci = ratio_ci(base, cand, 'p50', n_boot=300, seed=case)
        assert ci is not None
        covered += ci[0] <= true_ratio <= ci[1]
    assert 0.88 <= covered / cases <= 0.99


def test_too_few_frames_give_no_replicates_and_no_interval() -> None:
    short = np.arange(1.0, MIN_FRAMES)
    assert replicates(short, None, rng=np.random.default_rng(0)) is None
    assert ratio_ci(short, short)[1] is None
    assert percentile_interval([1.0, np.inf]) is None
    assert percentile_interval([]) is None


def test_throughput_replicates_come_from_the_completion_intervals() -> None:
    lat = np.full(100, 5.0)
    intervals = np.full(100, 0.01)  # one frame done every 10 ms
    reps = replicates(lat, intervals, n_boot=50, rng=np.random.default_rng(0))
    assert reps is not None
    assert reps.fps is not None
    np.testing.assert_allclose(reps.fps, 100.0)
    np.testing.assert_allclose(reps.mean, 5.0)


def test_two_thousand_resamples_of_ten_thousand_frames_take_well_under_a_second() -> None:
    lat = np.random.default_rng(0).gamma(5.0, 1.0, 10_000)
    intervals = lat / 1e3
    t0 = time.perf_counter()
    reps = replicates(lat, intervals, n_boot=2000, rng=np.random.default_rng(0))
    elapsed = time.perf_counter() - t0
    assert reps is not None
    assert reps.p99.shape == (2000,)
    assert elapsed < 1.0, f'{elapsed:.2f} s for one series'
