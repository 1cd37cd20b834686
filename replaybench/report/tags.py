"""The report's tag accuracy section: one row per (backend, topic) scored against tag truth."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.markup import escaped

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import SummaryRow

__all__ = ['tag_accuracy_html']

_COLUMNS = (
    ('recall', 'recall', '.3f'),
    ('matched', 'matched', 'd'),
    ('n_truth', 'truth', 'd'),
    ('wrong_ids', 'wrong ids', 'd'),
    ('phantoms', 'phantoms', 'd'),
    ('corner_rmse_px', 'corner RMSE px', '.3f'),
    ('trans_err_m', 'translation m', '.4f'),
    ('trans_err_pct', 'translation % of range', '.2f'),
    ('rot_err_deg', 'rotation deg', '.2f'),
    ('rot_err_deg_p95', 'rotation p95 deg', '.2f'),
    ('rot_err_deg_max', 'rotation max deg', '.2f'),
)


def tag_accuracy_html(rows: Sequence[SummaryRow]) -> str:
    """The section, or '' when no row has tag accuracy."""
    scored = [row for row in rows if row.tag_accuracy is not None]
    if not scored:
        return ''
    head = ''.join(f'<th class="n">{escaped(title)}</th>' for _, title, _ in _COLUMNS)
    body = []
    for row in scored:
        acc = row.tag_accuracy
        assert acc is not None
        cells = []
        for key, _, spec in _COLUMNS:
            value = getattr(acc, key)
            cells.append(
                f'<td class="n">{"-" if value is None else escaped(format(value, spec))}</td>'
            )
        body.append(
            f'<tr><td>{escaped(row.backend)}</td><td><code>{escaped(row.topic)}</code></td>'
            + ''.join(cells)
            + '</tr>'
        )
    return (
        '<h2 id="tags">Tag accuracy</h2>'
        '<p class="muted">Against the tag ground truth (docs/fiducials.md): a truth tag is matched '
        'by a detected tag of its id whose centre lies inside it; errors over the matched tags, '
        'poses where both have one. Point estimates, no interval.</p>'
        '<div class="table-wrap">'
        f'<table id="tag-accuracy"><thead><tr><th>backend</th><th>topic</th>{head}</tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>'
    )
