"""The interval the gate judges: between blocks of frames, or between frames for short runs.

A run's frames are not independent draws. Background load, frequency scaling and other
processes come and go in phases that slow whole stretches of a run, so two runs of the same
code differ by more than frame-to-frame noise predicts, mostly in the mean and the tail.
Intervals built from frames alone (a bootstrap of frames) then call such a difference
significant. So the gate compares **blocks**:

- each run's measured frames, in replay order, are cut into ``k`` blocks of consecutive
  frames, ``k = clamp(n // BLOCK_FRAMES, MIN_BLOCKS, MAX_BLOCKS)`` (10 blocks of 30 frames for
  300 frames; 20 blocks from 600 frames on, longer blocks after that);
- the metric is computed in each block (block median, block p99, block mean, block
  throughput = frames / the block's completion-to-completion time);
- the candidate's blocks are compared with the baseline's by the exact rank interval of
  ``exact.py``: the Hodges–Lehmann ratio (or difference) of the typical block and its Moses
  interval.

A stretch slowed by a load phase makes a few blocks slow; rank statistics give those blocks no
more weight than any other, so the typical block — and the verdict — moves only when the
change is in most of the run, as a change of code is. The price: a change confined to a few
stretches of a run is not called a regression (it cannot be told from interference with one
pair of runs).

Short runs (fewer than ``MIN_FRAMES`` measured frames on either side) have no blocks: their
frames themselves are compared, by the same exact interval, under the scale model (the
candidate's latencies are the baseline's times a common factor, which is what ten frames can
tell; every latency metric gets the interval of that factor, throughput that of the per-frame
rates ``1 / interval``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from replaybench.results.bootstrap import MIN_FRAMES
from replaybench.results.exact import ratio_interval, shift_interval

if TYPE_CHECKING:
    import numpy.typing as npt

__all__ = [
    'BLOCK_FRAMES',
    'MAX_BLOCKS',
    'MIN_BLOCKS',
    'ChangeInterval',
    'block_count',
    'block_values',
    'change_interval',
    'point_value',
]

#: Frames per block aimed at (blocks are longer once there would be more than MAX_BLOCKS).
BLOCK_FRAMES = 30
#: Fewest blocks per run: 4 against 4 is the smallest comparison whose 95 % interval can
#: exclude anything (2 / C(8, 4) = 2.9 %).
MIN_BLOCKS = 4
#: Most blocks per run.
MAX_BLOCKS = 20

_LATENCY = {'median_ms', 'p99_ms', 'mean_ms'}


class ChangeInterval(NamedTuple):
    """How a candidate's metric differs from its baseline's, by the gate's method.

    ``ratio`` / ``diff`` are the Hodges–Lehmann estimates (typical block, or typical frame),
    ``ratio_ci`` / ``diff_ci`` their exact rank intervals; ``blocks`` the block counts
    (baseline, candidate), None when frames were compared.
    """

    method: str
    blocks: tuple[int, int] | None
    ratio: float | None
    ratio_ci: tuple[float, float] | None
    diff: float | None
    diff_ci: tuple[float, float] | None


def block_count(n: int) -> int:
    """Blocks a series of ``n`` measured frames is cut into (0 below ``MIN_FRAMES``)."""
    if n < MIN_FRAMES:
        return 0
    return min(MAX_BLOCKS, max(MIN_BLOCKS, n // BLOCK_FRAMES))


def _array(values: npt.ArrayLike | None) -> npt.NDArray[np.float64] | None:
    if values is None:
        return None
    return np.asarray(values, dtype=np.float64).reshape(-1)


def point_value(
    metric: str, latency_ms: npt.ArrayLike, intervals_s: npt.ArrayLike | None = None
) -> float | None:
    """The metric of a whole series, as summary.csv defines it (linear percentiles, throughput
    = frames / the sum of completion-to-completion times)."""
    lat = _array(latency_ms)
    if lat is None or not lat.size:
        return None
    if metric == 'median_ms':
        return float(np.percentile(lat, 50, method='linear'))
    if metric == 'p99_ms':
        return float(np.percentile(lat, 99, method='linear'))
    if metric == 'mean_ms':
        return float(np.mean(lat))
    iv = _array(intervals_s)
    if metric != 'fps' or iv is None or iv.size != lat.size:
        return None
    total = float(np.sum(iv))
    return lat.size / total if total > 0 else None


def block_values(
    metric: str,
    latency_ms: npt.ArrayLike,
    intervals_s: npt.ArrayLike | None,
    blocks: int,
) -> npt.NDArray[np.float64] | None:
    """The metric in each of ``blocks`` blocks of consecutive frames (sizes differ by at most
    one frame); None when it cannot be computed (throughput without intervals)."""
    lat = _array(latency_ms)
    if lat is None or blocks < 1 or lat.size < blocks:
        return None
    if metric in _LATENCY:
        return np.asarray(
            [point_value(metric, part) for part in np.array_split(lat, blocks)],
            dtype=np.float64,
        )
    iv = _array(intervals_s)
    if metric != 'fps' or iv is None or iv.size != lat.size:
        return None
    sums = np.asarray([part.sum() for part in np.array_split(iv, blocks)], dtype=np.float64)
    sizes = np.asarray([part.size for part in np.array_split(iv, blocks)], dtype=np.float64)
    with np.errstate(divide='ignore', invalid='ignore'):
        rates: npt.NDArray[np.float64] = sizes / sums
    return rates


def _frame_values(
    metric: str, latency_ms: npt.ArrayLike, intervals_s: npt.ArrayLike | None
) -> npt.NDArray[np.float64] | None:
    lat = _array(latency_ms)
    if lat is None:
        return None
    if metric in _LATENCY:
        return lat
    iv = _array(intervals_s)
    if metric != 'fps' or iv is None or iv.size != lat.size:
        return None
    with np.errstate(divide='ignore', invalid='ignore'):
        rates: npt.NDArray[np.float64] = 1.0 / iv
    return rates


def change_interval(
    metric: str,
    baseline_ms: npt.ArrayLike,
    candidate_ms: npt.ArrayLike,
    *,
    baseline_intervals_s: npt.ArrayLike | None = None,
    candidate_intervals_s: npt.ArrayLike | None = None,
    confidence: float,
) -> ChangeInterval:
    """The gate's ratio and difference intervals of ``metric`` (``median_ms``, ``p99_ms``,
    ``mean_ms`` or ``fps``) between a baseline and a candidate series in replay order."""
    base = _array(baseline_ms)
    cand = _array(candidate_ms)
    nb = 0 if base is None else base.size
    nc = 0 if cand is None else cand.size
    kb, kc = block_count(nb), block_count(nc)
    if kb and kc:
        method = 'between-block'
        blocks: tuple[int, int] | None = (kb, kc)
        x = block_values(metric, baseline_ms, baseline_intervals_s, kb)
        y = block_values(metric, candidate_ms, candidate_intervals_s, kc)
    else:
        method = 'per-frame'
        blocks = None
        x = _frame_values(metric, baseline_ms, baseline_intervals_s)
        y = _frame_values(metric, candidate_ms, candidate_intervals_s)
    if x is None or y is None:
        return ChangeInterval(method, blocks, None, None, None, None)
    ratio, ratio_ci = ratio_interval(x, y, confidence)
    diff, diff_ci = shift_interval(x, y, confidence)
    return ChangeInterval(method, blocks, ratio, ratio_ci, diff, diff_ci)
