"""The detections task's parts of report.html: its columns of the Summary's "More figures"
table and the average precision per class under the Summary (``DetectionsTask.views``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.formats import fmt
from replaybench.report.markup import escaped
from replaybench.tasks.detections.task import DetectionsTask

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import SummaryRow

__all__ = ['accuracy_details_html', 'more_columns']

_LABELS = {m.name: m.short_label for m in DetectionsTask.metrics}
#: (field, heading) of the "More figures" columns: P and R at IoU 0.5, mAP over IoU 0.5:0.95
_MORE = (
    ('precision50', _LABELS['precision50']),
    ('recall50', _LABELS['recall50']),
    ('map50_95', 'mAP@0.5:0.95'),
)


def _accuracy_value(row: SummaryRow, key: str) -> float | None:
    """A row's accuracy figure: from its full ``accuracy`` when it has one."""
    value: float | None = getattr(row.accuracy if row.accuracy is not None else row, key)
    return value


def more_columns(rows: Sequence[SummaryRow]) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """P@0.5, R@0.5 and mAP@0.5:0.95 of each row; no columns when no row was scored."""
    if not any(r.accuracy is not None or r.map50 is not None for r in rows):
        return (), [() for _ in rows]
    headings = tuple(heading for _, heading in _MORE)
    return headings, [tuple(fmt(_accuracy_value(row, key), 3) for key, _ in _MORE) for row in rows]


def accuracy_details_html(rows: Sequence[SummaryRow]) -> str:
    """The average precision of each class at IoU 0.5 and 0.5:0.95, per scored row."""
    parts = []
    for row in rows:
        acc = row.accuracy
        if acc is None or (not acc.ap50 and not acc.ap50_95):
            continue
        ap50, ap50_95 = acc.ap50, acc.ap50_95
        labels = sorted(set(ap50) | set(ap50_95))
        body = ''.join(
            f'<tr><td>{escaped(label)}</td><td class="n">{escaped(fmt(ap50.get(label), 3))}</td>'
            f'<td class="n">{escaped(fmt(ap50_95.get(label), 3))}</td></tr>'
            for label in labels
        )
        counts = ', '.join(
            f'{name} {value}'
            for name, value in (('frames', acc.frames), ('n_gt', acc.n_gt), ('n_det', acc.n_det))
            if value is not None
        )
        parts.append(
            f'<h3>{escaped(row.backend or "?")} · <code>{escaped(row.topic or "?")}</code></h3>'
            + (f'<p class="muted">{escaped(counts)}</p>' if counts else '')
            + '<table><thead><tr><th>class</th><th class="n">AP@0.5</th>'
            f'<th class="n">AP@0.5:0.95</th></tr></thead><tbody>{body}</tbody></table>',
        )
    if not parts:
        return ''
    return '<details><summary>Average precision per class</summary>' + ''.join(parts) + '</details>'
