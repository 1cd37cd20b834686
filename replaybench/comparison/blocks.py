"""The gate's between-block intervals, re-exported from ``replaybench.results.blocks`` (run
reports judge drift with them too)."""

from __future__ import annotations

from replaybench.results.blocks import (
    BLOCK_FRAMES,
    MAX_BLOCKS,
    MIN_BLOCKS,
    ChangeInterval,
    block_count,
    block_values,
    change_interval,
    point_value,
)

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
