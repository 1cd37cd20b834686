"""The tracks task on report.html: its figures other than HOTA (the Summary's main column) in
the Summary's "More figures" table, for the rows that have them."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.tasks.tracks.task import TASK

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import SummaryRow

__all__ = ['more_columns']

#: counts, shown without decimals
_COUNTS = frozenset({'id_switches', 'fragmentations'})


def more_columns(rows: Sequence[SummaryRow]) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """Each tracking figure but HOTA that some row has, headed by its short label ('–' in the
    rows without it)."""
    specs = [m for m in TASK.metrics if not m.main]
    shown = [m for m in specs if any(r.metric(m.name) is not None for r in rows)]
    cells = [
        tuple(
            '–'
            if (v := r.metric(m.name)) is None
            else f'{v:.0f}'
            if m.name in _COUNTS
            else f'{v:.3f}'
            for m in shown
        )
        for r in rows
    ]
    return tuple(m.short_label for m in shown), cells
