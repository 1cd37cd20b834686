"""report.html's Summary table, its intervals, and the average precision per class."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.report.formats import fmt, fmt_fps, fmt_ms, fmt_value
from replaybench.report.markup import escaped
from replaybench.results.numbers import finite_number
from replaybench.results.recorded_latency import replays_recording

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from replaybench.results.model import SummaryRow

__all__ = ['accuracy_details_html', 'summary_html']


def _accuracy_value(row: SummaryRow, key: str) -> float | None:
    """A row's accuracy figure: from its full ``accuracy`` when it has one."""
    value: float | None = getattr(row.accuracy if row.accuracy is not None else row, key)
    return value


def _map50(row: SummaryRow) -> float | None:
    return _accuracy_value(row, 'map50')


def _tag_recall(row: SummaryRow) -> float | None:
    return row.tag_accuracy.recall if row.tag_accuracy is not None else row.tag_recall


def _miou(row: SummaryRow) -> float | None:
    return row.miou


#: The main accuracy figure of each task, the one a reader looks for first: boxes' mAP@0.5,
#: tags' recall, masks' mIoU (title, figure of a row).
_MAIN_ACCURACY: tuple[tuple[str, Callable[[SummaryRow], float | None]], ...] = (
    ('mAP@0.5', _map50),
    ('tag recall', _tag_recall),
    ('mIoU', _miou),
)

_RECORDED_TIP = (
    "recorded: the robot's node, from the bag (output rate; pipeline latency, output log time "
    '− image log time), not a replay on this machine'
)


def _recorded_cell(value: float | None, low: Any, high: Any, fmt: Callable[[Any], str]) -> str:
    """A ``recorded`` row's figure, marked as recorded (its replay is not timed)."""
    cell = f'<td class="n recorded" title="{escaped(_RECORDED_TIP)}">{escaped(fmt(value))}'
    if finite_number(low) is not None and finite_number(high) is not None:
        cell += f'<br><span class="muted ci">{escaped(fmt(low))}–{escaped(fmt(high))}</span>'
    return cell + '<br><span class="muted">recorded</span></td>'


def _speed_cells(row: SummaryRow) -> list[str]:
    """FPS, p50 and p99 of a row: replayed, or for a recording its recorded output rate and
    pipeline latency, marked so (how fast the bag was read is no detector's speed)."""
    if replays_recording(row):
        return [
            _recorded_cell(row.recorded_output_hz, None, None, fmt_fps),
            _recorded_cell(
                row.pipeline_ms_p50,
                row.pipeline_ms_p50_ci_low,
                row.pipeline_ms_p50_ci_high,
                fmt_ms,
            ),
            _recorded_cell(
                row.pipeline_ms_p99,
                row.pipeline_ms_p99_ci_low,
                row.pipeline_ms_p99_ci_high,
                fmt_ms,
            ),
        ]
    return [
        _with_ci(
            row.throughput_fps, row.throughput_fps_ci_low, row.throughput_fps_ci_high, fmt_fps
        ),
        _with_ci(row.latency_ms_p50, row.latency_ms_p50_ci_low, row.latency_ms_p50_ci_high, fmt_ms),
        _with_ci(row.latency_ms_p99, row.latency_ms_p99_ci_low, row.latency_ms_p99_ci_high, fmt_ms),
    ]


def _topic_html(topic: str) -> str:
    """A topic name that may break after each '/' (narrow columns)."""
    return f'<code>{escaped(topic).replace("/", "/<wbr>")}</code>'


def summary_html(rows: Sequence[SummaryRow], colours: Mapping[str, str]) -> str:
    """The figures read first (frames, drops, FPS, p50, p99, the task's main accuracy), narrow
    enough for a laptop's screen; the others in a table that opens below it."""
    accuracy = any(r.accuracy is not None or r.map50 is not None for r in rows)
    main = [(t, get) for t, get in _MAIN_ACCURACY if any(get(r) is not None for r in rows)]
    head = ['backend', 'topic', 'measured', 'dropped', 'FPS', 'p50 ms', 'p99 ms']
    head += [title for title, _ in main]
    more_head = ['backend', 'topic', 'skipped', 'p95 ms', 'max ms', 'jitter ms', 'det/frame']
    if accuracy:
        more_head += ['P@0.5', 'R@0.5', 'mAP@0.5:0.95']

    def th(names: Sequence[str]) -> str:
        return ''.join(
            f'<th class="n">{escaped(n)}</th>' if i >= 2 else f'<th>{escaped(n)}</th>'
            for i, n in enumerate(names)
        )

    body, more = [], []
    for row in rows:
        backend = row.backend or '?'
        swatch = f'<span class="swatch" style="background:{colours.get(backend, "#777")}"></span>'
        where = [
            f'<td>{swatch}{escaped(backend)}</td>',
            f'<td>{_topic_html(row.topic or "?")}</td>',
        ]
        cells = [
            *where,
            f'<td class="n">{escaped(fmt_value(row.measured))}</td>',
            f'<td class="n">{escaped(fmt_value(row.dropped))}</td>',
            *_speed_cells(row),
            *(f'<td class="n">{escaped(fmt(get(row), 3))}</td>' for _, get in main),
        ]
        body.append(f'<tr>{"".join(cells)}</tr>')
        recorded = replays_recording(row)
        extra = [
            *where,
            f'<td class="n">{escaped(fmt_value(row.skipped))}</td>',
            *(
                f'<td class="n">{escaped("–" if recorded else fmt_ms(v))}</td>'
                for v in (row.latency_ms_p95, row.latency_ms_max, row.jitter_ms)
            ),
            f'<td class="n">{escaped(fmt(row.detections_per_frame))}</td>',
        ]
        if accuracy:
            extra.extend(
                f'<td class="n">{escaped(fmt(_accuracy_value(row, key), 3))}</td>'
                for key in ('precision50', 'recall50', 'map50_95')
            )
        more.append(f'<tr>{"".join(extra)}</tr>')
    notes = (
        'Statistics cover measured frames only (processed, after warm-up). '
        'FPS: measured frames per second of processing window. Under FPS, p50 and p99: the 95 % '
        'interval (block bootstrap of the measured frames, as in replaybench compare; none under '
        '20 measured frames).'
    )
    if any(replays_recording(r) for r in rows):
        notes += (
            ' Marked recorded: a backend replaying the outputs recorded in the bag; its FPS is the '
            "rate the robot's node published at and its p50 and p99 are its recorded pipeline "
            'latency (output log time − image log time), not figures of this machine.'
        )
    return (
        f'<div class="table-wrap"><table id="summary-table"><thead><tr>{th(head)}</tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>'
        f'<p class="muted">{escaped(notes)}</p>'
        f'<details id="summary-more"><summary>More figures: {escaped(", ".join(more_head[2:]))}'
        f'</summary><div class="table-wrap"><table id="summary-more-table"><thead><tr>'
        f'{th(more_head)}</tr></thead><tbody>{"".join(more)}</tbody></table></div>'
        '<p class="muted">jitter: mean absolute difference of consecutive latencies.</p>'
        '</details>'
    )


def _with_ci(
    value: float | None, low: float | None, high: float | None, fmt: Callable[[Any], str]
) -> str:
    """A number's cell, its 95 % interval under it when there is one."""
    cell = f'<td class="n">{escaped(fmt(value))}'
    if finite_number(low) is not None and finite_number(high) is not None:
        cell += f'<br><span class="muted ci">{escaped(fmt(low))}–{escaped(fmt(high))}</span>'
    return cell + '</td>'


def accuracy_details_html(rows: Sequence[SummaryRow]) -> str:
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


# --------------------------------------------------------------------------- plots
