"""One metric of a compare row against its baseline row (``MetricComparison``), in a module of
its own so that every kind of metric (timing, accuracy, recorded latency) is built as one."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ['Interval', 'MetricComparison']

Interval = tuple[float, float]


@dataclass(frozen=True, slots=True)
class MetricComparison:
    """One metric of one row against its baseline row.

    ``ratio`` is candidate / baseline and ``diff`` candidate - baseline, of the whole runs (the
    summary.csv values). ``value_ci`` is the block-bootstrap interval of the row's own value.
    ``ratio_ci`` and ``diff_ci`` are the intervals the gate judges (timing metrics only;
    accuracy metrics have none): exact rank intervals of the typical change between blocks of
    frames, or between frames for short runs (``method``: ``between-block`` or ``per-frame``;
    blocks.py); ``typical_ratio`` / ``typical_diff`` are their Hodges–Lehmann centres.
    ``significant`` is None without a CI, else whether the ratio CI excludes 1.0.
    """

    metric: str
    value: float | None
    value_ci: Interval | None = None
    baseline: float | None = None
    ratio: float | None = None
    ratio_ci: Interval | None = None
    diff: float | None = None
    diff_ci: Interval | None = None
    typical_ratio: float | None = None
    typical_diff: float | None = None
    method: str | None = None
    #: blocks compared (baseline, candidate); None when frames were compared
    blocks: tuple[int, int] | None = None

    @property
    def significant(self) -> bool | None:
        """Whether the ratio CI excludes 1.0; None when there is no CI."""
        if self.ratio_ci is None:
            return None
        lo, hi = self.ratio_ci
        return not lo <= 1.0 <= hi
