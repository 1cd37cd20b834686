"""The registered tasks' parts of report.html, loaded when a report is rendered.

Each task (``replaybench.tasks``) names its parts in its ``TaskViews`` as ``'module:attr'``
strings; they are imported here, in the tasks' registry order, so that the report's sections
loop over the tasks instead of naming them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

from replaybench.tasks import TaskViews, get_task, load_view, task_names, task_views

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from replaybench.results.model import SummaryRow
    from replaybench.tasks import MetricSpec

    Rows = Sequence[SummaryRow]
    Panel = Callable[[Rows], str]
    Columns = Callable[[Rows], tuple[tuple[str, ...], list[tuple[str, ...]]]]

__all__ = ['ReportParts', 'main_value', 'metric_columns', 'report_parts']


@dataclass(frozen=True, slots=True)
class ReportParts:
    """What the tasks add to report.html, each list in the tasks' order."""

    #: each task's main figure (``MetricSpec.main``), a column of the Summary table
    main: tuple[MetricSpec, ...]
    #: HTML right under the Summary table
    summary_panels: tuple[Panel, ...]
    #: columns of the Summary's "More figures" table
    more_columns: tuple[Columns, ...]
    #: sections after the recorded latency
    sections: tuple[Panel, ...]


def main_value(row: SummaryRow, spec: MetricSpec) -> float | None:
    """A row's value of a task's main figure (``SummaryRow.metric``); None where the row has
    none."""
    return row.metric(spec.name)


def metric_columns(specs: Sequence[MetricSpec]) -> Columns:
    """The "More figures" columns of a task that declares no views (``TaskViews``): each
    metric of ``specs`` that a row has (``SummaryRow.metric``), headed by its short label,
    its value with the terminal's digits ('–' in the other rows)."""

    def columns(rows: Rows) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
        shown = [m for m in specs if any(r.metric(m.name) is not None for r in rows)]
        cells = [
            tuple(
                '–' if (v := r.metric(m.name)) is None else f'{v:.{m.terminal_digits}f}'
                for m in shown
            )
            for r in rows
        ]
        return tuple(m.short_label for m in shown), cells

    return columns


def report_parts() -> ReportParts:
    """The parts of every registered task, imported now.

    ``TaskUnavailableError`` when a task or one of its views cannot be loaded.
    """
    main: list[MetricSpec] = []
    summary: list[Panel] = []
    columns: list[Columns] = []
    sections: list[Panel] = []
    for name in task_names():
        task = get_task(name)
        main += [m for m in task.metrics if m.main][:1]
        views = task_views(task)
        if views.summary_panel is not None:
            summary.append(cast('Panel', load_view(task, views.summary_panel)))
        if views.more_columns is not None:
            columns.append(cast('Columns', load_view(task, views.more_columns)))
        elif views == TaskViews():  # a task that declares no views: its metrics shown plainly
            columns.append(metric_columns(tuple(m for m in task.metrics if not m.main)))
        if views.section_panel is not None:
            sections.append(cast('Panel', load_view(task, views.section_panel)))
    return ReportParts(tuple(main), tuple(summary), tuple(columns), tuple(sections))
