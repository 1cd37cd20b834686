"""The circular block bootstrap, re-exported from ``replaybench.results.bootstrap`` (where run
reports compute their intervals with it too)."""

from __future__ import annotations

from replaybench.results.bootstrap import (
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    MIN_FRAMES,
    Replicates,
    block_length,
    block_starts,
    block_sums,
    percentile_interval,
    politis_white_length,
    quantile_replicates,
    ratio_ci,
    replicates,
)

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
