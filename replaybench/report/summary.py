"""report.html's Summary table and its intervals; the tasks' main figures and columns in it
come from the registered tasks (``replaybench.report.taskviews``)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.report.formats import fmt, fmt_fps, fmt_ms, fmt_value
from replaybench.report.markup import escaped
from replaybench.report.taskviews import main_value
from replaybench.results.numbers import finite_number
from replaybench.results.recorded_latency import replays_recording

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from replaybench.report.taskviews import ReportParts
    from replaybench.results.model import SummaryRow

__all__ = ['summary_html']


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


def summary_html(rows: Sequence[SummaryRow], colours: Mapping[str, str], parts: ReportParts) -> str:
    """The figures read first (frames, drops, FPS, p50, p99, each task's main figure where a
    row has it), narrow enough for a laptop's screen; the others, the tasks' columns among
    them, in a table that opens below it."""
    main = [m for m in parts.main if any(main_value(r, m) is not None for r in rows)]
    head = ['backend', 'topic', 'measured', 'dropped', 'FPS', 'p50 ms', 'p99 ms']
    head += [m.short_label for m in main]
    more_head = ['backend', 'topic', 'skipped', 'p95 ms', 'max ms', 'jitter ms', 'det/frame']
    task_cells: list[list[str]] = [[] for _ in rows]
    for columns in parts.more_columns:
        headings, by_row = columns(rows)
        if headings:
            more_head += headings
            for mine, texts in zip(task_cells, by_row, strict=True):
                mine += texts

    def th(names: Sequence[str]) -> str:
        return ''.join(
            f'<th class="n">{escaped(n)}</th>' if i >= 2 else f'<th>{escaped(n)}</th>'
            for i, n in enumerate(names)
        )

    body, more = [], []
    for row, task_texts in zip(rows, task_cells, strict=True):
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
            *(f'<td class="n">{escaped(fmt(main_value(row, m), 3))}</td>' for m in main),
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
            *(f'<td class="n">{escaped(text)}</td>' for text in task_texts),
        ]
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
