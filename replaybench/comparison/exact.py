"""Exact rank intervals, re-exported from ``replaybench.results.exact`` (run reports judge
drift with them too)."""

from __future__ import annotations

from replaybench.results.exact import (
    mann_whitney_null,
    moses_cut,
    ratio_interval,
    shift_interval,
)

__all__ = ['mann_whitney_null', 'moses_cut', 'ratio_interval', 'shift_interval']
