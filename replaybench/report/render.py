"""report.html: one self-contained page (inline CSS, inline SVG, embedded images) per run folder."""

from __future__ import annotations

import base64
import dataclasses
import json
import math
import shlex
from html import escape
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

from replaybench.errors import SourceError
from replaybench.report.headline import headline_html
from replaybench.report.masks import mask_of
from replaybench.report.recorded import recorded_latency_html
from replaybench.report.samples import sample_relpath
from replaybench.report.svg import (
    TREND_POINTS,
    Marks,
    Rule,
    Segment,
    Series,
    bar_chart,
    colour,
    line_chart,
    nice_ticks,
    stacked_bar_chart,
    step_cdf,
)
from replaybench.report.tags import tag_accuracy_html
from replaybench.results.atomic import write_text_atomic
from replaybench.results.folder import load_run
from replaybench.results.intervals import with_intervals
from replaybench.results.io import read_peak_result, to_json
from replaybench.results.model import PEAK_SCHEMA_VERSION, ResourceSummary, SummaryRow
from replaybench.results.recorded_latency import replays_recording, with_recorded_latency
from replaybench.results.repeats import one_timeline
from replaybench.results.stats import summarize
from replaybench.textsafe import visible, visible_lines

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Mapping, Sequence

    from replaybench.results.folder import RunData
    from replaybench.results.model import (
        AgreementRow,
        Environment,
        PeakResult,
        ResourcePoint,
        RunResult,
    )
    from replaybench.results.records import FrameRecord

__all__ = [
    'PEAK_SCHEMA_VERSION',
    'load_peak',
    'render_html',
    'render_peak_html',
    'render_peak_report',
    'render_report',
]

_MAX_SAMPLE_BYTES = 4 << 20
_CHART_PIXELS = 640  # plot-area width of the default 720 px charts
_IMAGE_TYPES = {'.jpg': 'image/jpeg', '.jpeg': 'image/jpeg', '.png': 'image/png'}

#: (summary key, legend name, colour) of the stage breakdown, in stacking order.
_STAGES: tuple[tuple[str, str, str], ...] = (
    ('queue_wait_ms_mean', 'queue wait', '#bab0ac'),
    ('read_decode_ms_mean', 'read + decode', '#4e79a7'),
    ('preprocess_ms_mean', 'preprocess', '#f28e2b'),
    ('infer_ms_mean', 'infer', '#e15759'),
    ('postprocess_ms_mean', 'postprocess', '#76b7b2'),
    ('h2d_ms_mean', 'host→device', '#59a14f'),
    ('d2h_ms_mean', 'device→host', '#edc948'),
)

_CSS = """
:root{--fg:#1d1d1f;--muted:#666;--line:#ddd;--bg:#fff;--soft:#f6f7f9}
*{box-sizing:border-box}
body{margin:0;font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;
color:var(--fg);background:var(--bg)}
main{max-width:1180px;margin:0 auto;padding:20px 24px 48px}
h1{font-size:22px;margin:0 0 4px}
h2{font-size:18px;margin:28px 0 10px;padding-bottom:4px;border-bottom:1px solid var(--line)}
h3{font-size:15px;margin:18px 0 8px}
.meta{color:var(--muted);margin:0 0 12px}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-weight:600;font-size:12px;
color:#fff;background:#777;vertical-align:2px}
.badge.complete{background:#2e7d32}.badge.interrupted{background:#e65100}
.badge.failed{background:#c62828}
.banner{border:1px solid #e0b000;background:#fff8e1;border-radius:6px;padding:10px 14px;
margin:12px 0}
.banner strong{display:block;margin-bottom:4px}
.banner ul{margin:4px 0 0;padding-left:20px}
.cards{display:grid;grid-template-columns:repeat(auto-fit,minmax(320px,1fr));gap:12px}
.card{background:var(--soft);border:1px solid var(--line);border-radius:6px;padding:10px 14px;
min-width:0;overflow-x:auto}
.card h3{margin:0 0 6px}
dl{display:grid;grid-template-columns:max-content 1fr;gap:2px 12px;margin:0}
dt{color:var(--muted)}dd{margin:0;overflow-wrap:anywhere}
table{border-collapse:collapse;width:100%;margin:6px 0 10px;font-variant-numeric:tabular-nums}
th,td{border-bottom:1px solid var(--line);padding:4px 8px;text-align:left;vertical-align:top}
th{background:var(--soft);font-weight:600;white-space:nowrap}
td.n,th.n{text-align:right;white-space:nowrap}
.swatch{display:inline-block;width:10px;height:10px;border-radius:2px;margin-right:6px}
.table-wrap{overflow-x:auto}
.charts{display:flex;flex-wrap:wrap;gap:10px}
svg.chart{max-width:100%;height:auto;background:#fff;border:1px solid var(--line);
border-radius:6px}
.samples{display:flex;flex-wrap:wrap;gap:12px}
figure{margin:0;max-width:482px}
figure img{max-width:100%;height:auto;border:1px solid var(--line);border-radius:4px}
figcaption{color:var(--muted);font-size:12px;overflow-wrap:anywhere}
code,pre{font:12px/1.4 ui-monospace,SFMono-Regular,Menlo,Consolas,monospace}
pre{background:var(--soft);border:1px solid var(--line);border-radius:6px;padding:10px;
overflow-x:auto;white-space:pre-wrap;overflow-wrap:anywhere}
details{margin:8px 0}summary{cursor:pointer;font-weight:600}
.muted{color:var(--muted)}
tr.peak td{font-weight:600;background:#eef7ee}
footer{margin-top:36px;color:var(--muted);font-size:12px}
@media print{svg.chart{border:none}details{display:block}}
"""


def _e(value: object) -> str:
    """HTML-escaped text, control characters shown as escapes (``replaybench.textsafe``)."""
    return escape(visible(str(value)), quote=True)


def _pre(text: str) -> str:
    """``_e`` for a ``<pre>`` block: its line feeds stay."""
    return escape(visible_lines(text), quote=True)


def _num(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def _int(value: Any) -> int | None:
    if isinstance(value, bool) or not isinstance(value, int):
        return None
    return value


def _dict(value: Any) -> dict[str, Any]:
    return value if isinstance(value, dict) else {}


def _list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else []


def _fmt_ms(value: Any) -> str:
    number = _num(value)
    if number is None:
        return '–'
    if abs(number) < 1:
        return f'{number:.3f}'
    if abs(number) < 100:
        return f'{number:.2f}'
    return f'{number:.1f}'


def _fmt(value: Any, digits: int = 2) -> str:
    number = _num(value)
    return '–' if number is None else f'{number:.{digits}f}'


def _fmt_fps(value: Any) -> str:
    number = _num(value)
    if number is None:
        return '–'
    return f'{number:.2f}' if number < 10 else f'{number:.1f}'


def _fmt_bytes(value: Any) -> str:
    number = _num(value)
    if number is None:
        return '–'
    if number < 1024:
        return f'{number:.0f} B'
    units = ('KiB', 'MiB', 'GiB', 'TiB')
    power = min(len(units), max(1, int(math.log(number, 1024))))
    return f'{number / 1024**power:.1f} {units[power - 1]}'


def _fmt_value(value: Any) -> str:
    if value is None:
        return '–'
    if isinstance(value, bool):
        return 'yes' if value else 'no'
    if isinstance(value, float):
        return f'{value:g}'
    if isinstance(value, list | dict):
        return json.dumps(value, ensure_ascii=False, sort_keys=True)
    return str(value)


def _dl(items: Iterable[tuple[str, Any]]) -> str:
    rows = ''.join(f'<dt>{_e(k)}</dt><dd>{_e(_fmt_value(v))}</dd>' for k, v in items)
    return f'<dl>{rows}</dl>'


def _backend_order(run: RunResult, frames: Sequence[FrameRecord]) -> list[str]:
    order: list[str] = []
    for entry in run.backends:
        label = entry.label or entry.name
        if label and label not in order:
            order.append(label)
    for record in frames:
        if record.backend not in order:
            order.append(record.backend)
    return order


def _topic_order(frames: Sequence[FrameRecord], rows: Sequence[SummaryRow]) -> list[str]:
    order: list[str] = []
    for topic in [r.topic for r in frames] + [r.topic for r in rows]:
        if topic not in order:
            order.append(topic)
    return order


def _summary_rows(run: RunResult, frames: Sequence[FrameRecord]) -> list[SummaryRow]:
    """run.json's summary rows; where it has none, those computed from frames.csv as the run
    would have written them, intervals and warnings included (throttling aside: that needs the
    resource samples)."""
    if run.summary_rows:
        return list(run.summary_rows)
    return with_recorded_latency(with_intervals(summarize(frames), frames), frames)


# --------------------------------------------------------------------------- header


def _header(run: RunResult) -> str:
    status = run.status
    meta = [
        f'<span class="badge {_e(status)}">{_e(status)}</span>',
        f'started {_e(run.started_at or "?")}',
    ]
    wall = _num(run.wall_s)
    if wall is not None:
        meta.append(f'wall time {wall:.1f} s')
    meta.append(f'{_e(run.tool.name)} {_e(run.tool.version or "?")}')
    return f'<header><h1>replaybench report</h1><p class="meta">{" · ".join(meta)}</p></header>'


def _banner(run: RunResult, frames: Sequence[FrameRecord], rows: Sequence[SummaryRow]) -> str:
    items: list[str] = []
    status = run.status
    if status == 'interrupted':
        items.append(
            'The run was interrupted: the numbers cover only the frames processed before it '
            'stopped.',
        )
    elif status != 'complete':
        items.append(f'The run ended with status {_e(status)}.')
    for entry in run.inputs:
        path = _e(entry.path or '?')
        if entry.truncated:
            items.append(
                f'Input <code>{path}</code> is truncated: only its complete messages were '
                'replayed.',
            )
        items.extend(f'<code>{path}</code>: {_e(warning)}' for warning in entry.warnings)
    skipped = dict(run.skipped)
    n_skipped = sum(1 for r in frames if r.status == 'skipped')
    if skipped or n_skipped:
        reasons = ''.join(
            f'<li>{_e(reason)}: {_e(count)}</li>' for reason, count in sorted(skipped.items())
        )
        total = sum(skipped.values()) or n_skipped
        items.append(
            f'{total} frame(s) were skipped because they could not be decoded'
            + (f'<ul>{reasons}</ul>' if reasons else '.'),
        )
    items += [_e(warning) for warning in run.warnings]
    for row in rows:
        where = f'<b>{_e(row.backend or "?")}</b> <code>{_e(row.topic or "?")}</code>'
        items += [f'{where}: {_e(warning)}' for warning in row.warnings]
    if not items:
        return ''
    body = ''.join(f'<li>{item}</li>' for item in items)
    return f'<div class="banner" role="alert"><strong>Warnings</strong><ul>{body}</ul></div>'


def _inputs_card(run: RunResult) -> str:
    rows = []
    for entry in run.inputs:
        sha = entry.sha256 or ''
        topics = ', '.join(t.name or '?' for t in entry.topics)
        flags = ' (truncated)' if entry.truncated else ''
        rows.append(
            f'<tr><td class="n">{_e(entry.index)}</td>'
            f'<td><code>{_e(entry.path or "?")}</code>{_e(flags)}'
            f'<br><span class="muted">{_e(topics)}</span></td>'
            f'<td>{_e(entry.format or "")}</td>'
            f'<td class="n">{_e(_fmt_bytes(entry.size_bytes))}</td>'
            f'<td><code title="{_e(sha)}">{_e(sha[:12])}</code></td></tr>',
        )
    table = (
        '<table><thead><tr><th class="n">#</th><th>path / topics</th><th>format</th>'
        f'<th class="n">size</th><th>sha256</th></tr></thead><tbody>{"".join(rows)}</tbody>'
        '</table>'
    )
    return f'<div class="card"><h3>Inputs</h3>{table}</div>'


def _environment_card(env: Environment) -> str:
    cpu, os_info, python, packages = env.cpu, env.os, env.python, env.packages
    opencv = packages.opencv
    gpus = [
        f'{g.name or "?"} ({g.memory_total or "?"}, driver {g.driver_version or "?"})'
        for g in env.gpus
    ]
    versions = [
        f'{f.name} {getattr(packages, f.name)}'
        for f in dataclasses.fields(packages)
        if isinstance(getattr(packages, f.name), str)
    ]
    if opencv.version:
        threads = opencv.threads if opencv.threads is not None else '?'
        versions.append(f'opencv {opencv.version} ({threads} threads)')
    cores, usable = cpu.logical_cores, cpu.usable_cores
    core_text = f'{cores}' + (f' ({usable} usable)' if usable not in (None, cores) else '')
    load = env.load_average
    items: list[tuple[str, Any]] = [
        ('host', env.hostname),
        ('CPU', cpu.model),
        ('cores', core_text),
        ('governor', cpu.governor),
        ('memory', _fmt_bytes(env.memory_total_bytes)),
        ('GPUs', '; '.join(gpus) if gpus else 'none found'),
        ('OS', os_info.platform or os_info.system),
        ('Python', f'{python.implementation or ""} {python.version or ""}'.strip()),
        ('packages', ', '.join(versions)),
        ('load average', ' '.join(_fmt_value(v) for v in load) if load else None),
    ]
    return f'<div class="card"><h3>Machine</h3>{_dl(items)}</div>'


def _settings_card(run: RunResult) -> str:
    backends = []
    for entry in run.backends:
        name, label = entry.name or '?', entry.label
        backends.append(f'{label} ({name})' if label and label != name else name)
    items: list[tuple[str, Any]] = [('backends', ', '.join(backends) or None)]
    items += list(to_json(run.settings).items())
    return f'<div class="card"><h3>Settings</h3>{_dl(items)}</div>'


# --------------------------------------------------------------------------- summary


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
    cell = f'<td class="n recorded" title="{_e(_RECORDED_TIP)}">{_e(fmt(value))}'
    if _num(low) is not None and _num(high) is not None:
        cell += f'<br><span class="muted ci">{_e(fmt(low))}–{_e(fmt(high))}</span>'
    return cell + '<br><span class="muted">recorded</span></td>'


def _speed_cells(row: SummaryRow) -> list[str]:
    """FPS, p50 and p99 of a row: replayed, or for a recording its recorded output rate and
    pipeline latency, marked so (how fast the bag was read is no detector's speed)."""
    if replays_recording(row):
        return [
            _recorded_cell(row.recorded_output_hz, None, None, _fmt_fps),
            _recorded_cell(
                row.pipeline_ms_p50,
                row.pipeline_ms_p50_ci_low,
                row.pipeline_ms_p50_ci_high,
                _fmt_ms,
            ),
            _recorded_cell(
                row.pipeline_ms_p99,
                row.pipeline_ms_p99_ci_low,
                row.pipeline_ms_p99_ci_high,
                _fmt_ms,
            ),
        ]
    return [
        _with_ci(
            row.throughput_fps, row.throughput_fps_ci_low, row.throughput_fps_ci_high, _fmt_fps
        ),
        _with_ci(
            row.latency_ms_p50, row.latency_ms_p50_ci_low, row.latency_ms_p50_ci_high, _fmt_ms
        ),
        _with_ci(
            row.latency_ms_p99, row.latency_ms_p99_ci_low, row.latency_ms_p99_ci_high, _fmt_ms
        ),
    ]


def _topic_html(topic: str) -> str:
    """A topic name that may break after each '/' (narrow columns)."""
    return f'<code>{_e(topic).replace("/", "/<wbr>")}</code>'


def _summary_table(rows: Sequence[SummaryRow], colours: Mapping[str, str]) -> str:
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
            f'<th class="n">{_e(n)}</th>' if i >= 2 else f'<th>{_e(n)}</th>'
            for i, n in enumerate(names)
        )

    body, more = [], []
    for row in rows:
        backend = row.backend or '?'
        swatch = f'<span class="swatch" style="background:{colours.get(backend, "#777")}"></span>'
        where = [f'<td>{swatch}{_e(backend)}</td>', f'<td>{_topic_html(row.topic or "?")}</td>']
        cells = [
            *where,
            f'<td class="n">{_e(_fmt_value(row.measured))}</td>',
            f'<td class="n">{_e(_fmt_value(row.dropped))}</td>',
            *_speed_cells(row),
            *(f'<td class="n">{_e(_fmt(get(row), 3))}</td>' for _, get in main),
        ]
        body.append(f'<tr>{"".join(cells)}</tr>')
        recorded = replays_recording(row)
        extra = [
            *where,
            f'<td class="n">{_e(_fmt_value(row.skipped))}</td>',
            *(
                f'<td class="n">{_e("–" if recorded else _fmt_ms(v))}</td>'
                for v in (row.latency_ms_p95, row.latency_ms_max, row.jitter_ms)
            ),
            f'<td class="n">{_e(_fmt(row.detections_per_frame))}</td>',
        ]
        if accuracy:
            extra.extend(
                f'<td class="n">{_e(_fmt(_accuracy_value(row, key), 3))}</td>'
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
        f'<p class="muted">{_e(notes)}</p>'
        f'<details id="summary-more"><summary>More figures: {_e(", ".join(more_head[2:]))}'
        f'</summary><div class="table-wrap"><table id="summary-more-table"><thead><tr>'
        f'{th(more_head)}</tr></thead><tbody>{"".join(more)}</tbody></table></div>'
        '<p class="muted">jitter: mean absolute difference of consecutive latencies.</p>'
        '</details>'
    )


def _with_ci(
    value: float | None, low: float | None, high: float | None, fmt: Callable[[Any], str]
) -> str:
    """A number's cell, its 95 % interval under it when there is one."""
    cell = f'<td class="n">{_e(fmt(value))}'
    if _num(low) is not None and _num(high) is not None:
        cell += f'<br><span class="muted ci">{_e(fmt(low))}–{_e(fmt(high))}</span>'
    return cell + '</td>'


def _accuracy_details(rows: Sequence[SummaryRow]) -> str:
    parts = []
    for row in rows:
        acc = row.accuracy
        if acc is None or (not acc.ap50 and not acc.ap50_95):
            continue
        ap50, ap50_95 = acc.ap50, acc.ap50_95
        labels = sorted(set(ap50) | set(ap50_95))
        body = ''.join(
            f'<tr><td>{_e(label)}</td><td class="n">{_e(_fmt(ap50.get(label), 3))}</td>'
            f'<td class="n">{_e(_fmt(ap50_95.get(label), 3))}</td></tr>'
            for label in labels
        )
        counts = ', '.join(
            f'{name} {value}'
            for name, value in (('frames', acc.frames), ('n_gt', acc.n_gt), ('n_det', acc.n_det))
            if value is not None
        )
        parts.append(
            f'<h3>{_e(row.backend or "?")} · <code>{_e(row.topic or "?")}</code></h3>'
            + (f'<p class="muted">{_e(counts)}</p>' if counts else '')
            + '<table><thead><tr><th>class</th><th class="n">AP@0.5</th>'
            f'<th class="n">AP@0.5:0.95</th></tr></thead><tbody>{body}</tbody></table>',
        )
    if not parts:
        return ''
    return '<details><summary>Average precision per class</summary>' + ''.join(parts) + '</details>'


# --------------------------------------------------------------------------- plots


def _spans(intervals: Iterable[tuple[float, float]]) -> list[tuple[float, float]]:
    merged: list[tuple[float, float]] = []
    for lo, hi in sorted(intervals):
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


def _median(values: Sequence[float]) -> float:
    ordered = sorted(values)
    mid = len(ordered) // 2
    return ordered[mid] if len(ordered) % 2 else (ordered[mid - 1] + ordered[mid]) / 2


def _latency_timeline(
    topic: str,
    groups: Mapping[str, Sequence[FrameRecord]],
    colours: Mapping[str, str],
) -> str:
    series: list[Series] = []
    marks: list[Marks] = []
    warm: list[tuple[float, float]] = []
    measured_max = 0.0
    medians: list[float] = []
    clipped = 0
    for backend, records in groups.items():
        ok = [r for r in records if r.status == 'ok' and r.latency_ms is not None]
        measured = [r.latency_ms for r in ok if not r.warmup and r.latency_ms is not None]
        if measured:
            measured_max = max(measured_max, max(measured))
            medians.append(_median(measured))
        series.append(
            Series(
                backend,
                colours[backend],
                [r.release_s for r in ok],
                [r.latency_ms for r in ok if r.latency_ms is not None],
            ),
        )
        warm_x = [r.release_s for r in ok if r.warmup]
        if warm_x:
            first_measured = min((r.release_s for r in ok if not r.warmup), default=max(warm_x))
            warm.append((min(warm_x), first_measured))
        dropped = [r.release_s for r in records if r.status == 'dropped']
        if dropped:
            marks.append(Marks(f'{backend} dropped ({len(dropped)})', colours[backend], dropped))
    y_range = None
    if measured_max > 0:
        top = nice_ticks(0.0, measured_max * 1.05, max_ticks=5)[-1]
        y_range = (0.0, top)
        clipped = sum(
            1
            for records in groups.values()
            for r in records
            if r.status == 'ok' and r.warmup and r.latency_ms is not None and r.latency_ms > top
        )
    positive = [m for m in medians if m > 0]
    log_y = len(positive) >= 2 and max(positive) / min(positive) > 10
    if log_y and y_range is not None:
        y_range = (min(positive) / 10, y_range[1])
    note = (
        f'{clipped} warm-up frame(s) above the axis are drawn at its top edge.' if clipped else ''
    )
    return line_chart(
        series,
        title=f'Latency over time · {topic}',
        x_label='release time since the backend started replaying (s)',
        y_label='latency (ms)' + (', log scale' if log_y else ''),
        y_range=y_range,
        log_y=log_y,
        spans=_spans(warm),
        span_label='warm-up' if warm else '',
        marks=marks,
        note=note,
        min_points=TREND_POINTS,
    )


def _latency_cdf(
    topic: str,
    groups: Mapping[str, Sequence[FrameRecord]],
    colours: Mapping[str, str],
) -> str:
    series = [
        (
            backend,
            colours[backend],
            [
                r.latency_ms
                for r in records
                if r.status == 'ok' and not r.warmup and r.latency_ms is not None
            ],
        )
        for backend, records in groups.items()
    ]
    return step_cdf(
        series, title=f'Latency CDF · {topic} (measured frames)', x_label='latency (ms)'
    )


def _detections_timeline(
    topic: str,
    groups: Mapping[str, Sequence[FrameRecord]],
    colours: Mapping[str, str],
) -> str:
    series = []
    longest = 0
    for backend, records in groups.items():
        ok = [r for r in records if r.status == 'ok' and r.detections is not None]
        longest = max(longest, len(ok))
        series.append(
            Series(
                backend,
                colours[backend],
                [r.release_s for r in ok],
                [float(r.detections) for r in ok if r.detections is not None],
            ),
        )
    return line_chart(
        series,
        title=f'Detections per frame · {topic}',
        x_label='release time since the backend started replaying (s)',
        y_label='detections',
        mean_per_pixel=True,
        note='Each point is the mean over the frames of one pixel column.'
        if longest > _CHART_PIXELS
        else '',
        min_points=TREND_POINTS,
    )


def _group_label(row: SummaryRow, many_topics: bool) -> str:
    backend = row.backend or '?'
    return f'{backend} · {row.topic or "?"}' if many_topics else backend


def _throughput_chart(
    rows: Sequence[SummaryRow],
    colours: Mapping[str, str],
    many_topics: bool,
) -> str:
    """Replayed rows only: a recording's rate of reading the bag is no detector's speed."""
    rows = [r for r in rows if not replays_recording(r)]
    if not rows:
        return ''
    return bar_chart(
        [_group_label(r, many_topics) for r in rows],
        [_num(r.throughput_fps) for r in rows],
        [colours.get(r.backend, '#777') for r in rows],
        title='Throughput (measured frames per second)',
        x_label='frames per second',
    )


def _stage_chart(rows: Sequence[SummaryRow], many_topics: bool) -> str:
    """Replayed rows only (a recording's stages did not run here)."""
    rows = [r for r in rows if not replays_recording(r)]
    if not rows:
        return ''
    segments = []
    for key, name, fill in _STAGES:
        values = [_num(getattr(r, key)) for r in rows]
        if not any(v for v in values):
            continue
        segments.append(Segment(name, fill, values))
    rest: list[float | None] = []
    for r in rows:
        mean = _num(r.latency_ms_mean)
        parts = [_num(getattr(r, key)) for key, _, _ in _STAGES]
        known = sum(p for p in parts if p is not None)
        rest.append(mean - known if mean is not None and mean - known > 1e-4 else None)
    if any(v is not None for v in rest):
        segments.append(Segment('other (not attributed to a stage)', '#d7d7d7', rest))
    return stacked_bar_chart(
        [_group_label(r, many_topics) for r in rows],
        segments,
        title='Mean latency by stage (measured frames)',
        x_label='milliseconds',
    )


def _plots(
    frames: Sequence[FrameRecord],
    rows: Sequence[SummaryRow],
    backends: Sequence[str],
    topics: Sequence[str],
    colours: Mapping[str, str],
) -> str:
    by_topic: dict[str, dict[str, list[FrameRecord]]] = {
        t: {b: [] for b in backends} for t in topics
    }
    for record in frames:
        by_topic[record.topic][record.backend].append(record)
    parts = ['<h2 id="latency">Latency</h2>']
    for topic in topics:
        groups = _by_release(by_topic[topic])
        if not groups:
            continue
        parts.append(
            f'<div class="charts">{_latency_timeline(topic, groups, colours)}'
            f'{_latency_cdf(topic, groups, colours)}</div>',
        )
    many_topics = len(topics) > 1
    parts.append('<h2 id="throughput">Throughput and stages</h2>')
    if rows:
        parts.append(
            f'<div class="charts">{_throughput_chart(rows, colours, many_topics)}'
            f'{_stage_chart(rows, many_topics)}</div>',
        )
    recordings = list(dict.fromkeys(r.backend for r in rows if replays_recording(r)))
    if recordings:
        parts.append(
            f'<p class="muted">Not charted here: {_e(", ".join(recordings))}, the outputs '
            'recorded in the bag. Their replay is no detector running on this machine: the '
            'rate they were read at is how fast the bag was read. Their recorded output rate '
            'and latency are in the Summary and under Recorded latency.</p>'
        )
    parts.append('<h2 id="detections">Detections</h2>')
    for topic in topics:
        groups = _by_release(by_topic[topic])
        if groups:
            parts.append(
                f'<div class="charts">{_detections_timeline(topic, groups, colours)}</div>'
            )
    return ''.join(parts)


# --------------------------------------------------------------------------- agreement


def _frame_name(key: tuple[int, int], single_input: bool) -> str:
    index, seq = key
    return f'#{seq}' if single_input else f'{index}:#{seq}'


def _fmt_frac(value: Any) -> str:
    number = _num(value)
    return '–' if number is None else f'{100 * number:.1f} %'


def _swatch(colours: Mapping[str, str], backend: str) -> str:
    return f'<span class="swatch" style="background:{_e(colours.get(backend, "#777"))}"></span>'


def _agreement(run: RunResult, colours: Mapping[str, str]) -> str:
    """Agreement between backends per topic, from run.json ``agreement``."""
    if not run.agreement:
        return ''
    single_input = len(run.inputs) <= 1
    threshold = run.settings.agreement_iou
    by_topic: dict[str, list[AgreementRow]] = {}
    for entry in run.agreement:
        by_topic.setdefault(entry.topic or '?', []).append(entry)
    head = (
        '<tr><th>backends (a / b)</th><th class="n">frames</th><th class="n">detections a</th>'
        '<th class="n">detections b</th><th class="n">matched</th><th class="n">of a</th>'
        '<th class="n">of b</th><th class="n">mean IoU</th><th class="n">mean |Δscore|</th>'
        '<th>most disagreeing frames</th></tr>'
    )
    intro = (
        f'Per frame both backends processed, detections of the same class are paired greedily '
        f'by IoU ≥ {threshold:g} (highest first). "of a" / "of b": share of each backend\'s '
        'detections that found a partner. No ground truth is involved. Most disagreeing frames '
        'first (most unmatched detections), as #seq of the topic.'
    )
    parts = [f'<h2 id="agreement">Agreement between backends</h2><p class="muted">{_e(intro)}</p>']
    for topic, rows in by_topic.items():
        body = []
        for entry in rows:
            a, b = entry.backend_a or '?', entry.backend_b or '?'
            frames = [_frame_name(k, single_input) for k in entry.disagreeing_frames]
            shown = ', '.join(frames[:6]) + (f' … (+{len(frames) - 6})' if len(frames) > 6 else '')
            body.append(
                f'<tr><td>{_swatch(colours, a)}{_e(a)} / {_swatch(colours, b)}{_e(b)}</td>'
                f'<td class="n">{_e(_fmt_value(entry.frames))}</td>'
                f'<td class="n">{_e(_fmt_value(entry.n_a))}</td>'
                f'<td class="n">{_e(_fmt_value(entry.n_b))}</td>'
                f'<td class="n">{_e(_fmt_value(entry.matched))}</td>'
                f'<td class="n">{_e(_fmt_frac(entry.matched_frac_a))}</td>'
                f'<td class="n">{_e(_fmt_frac(entry.matched_frac_b))}</td>'
                f'<td class="n">{_e(_fmt(entry.mean_iou, 3))}</td>'
                f'<td class="n">{_e(_fmt(entry.mean_abs_score_diff, 3))}</td>'
                f'<td title="{_e(", ".join(frames))}">{_e(shown) if frames else "none"}</td></tr>',
            )
        parts.append(
            f'<h3><code>{_e(topic)}</code></h3><div class="table-wrap"><table>'
            f'<thead>{head}</thead><tbody>{"".join(body)}</tbody></table></div>',
        )
    return ''.join(parts)


# --------------------------------------------------------------------------- resources

#: (series key, chart title, y label) of the resource charts, drawn when some backend has data.
_RESOURCE_CHARTS: tuple[tuple[str, str, str], ...] = (
    ('cpu_percent', 'CPU use over time', 'CPU (% of one core)'),
    ('private_mb', 'Private memory over time', 'private memory (MiB)'),
    ('rss_mb', 'Resident memory over time', 'RSS (MiB)'),
    ('gpu_util', 'GPU utilisation over time', 'GPU utilisation (%)'),
    ('gpu_mem_mb', 'GPU memory used over time', 'GPU memory (MiB)'),
)


#: The figures of a resource summary that a sampler measured (the rest describe the sampler).
_MEASURED: tuple[str, ...] = (
    'cpu_percent_mean',
    'private_mb_peak',
    'mapped_mb_peak',
    'rss_mb_peak',
    'gpu_util_mean',
    'gpu_mem_mb_peak',
    'gpu_power_w_mean',
)


def _resource_entries(
    run: RunResult,
) -> list[tuple[str, ResourceSummary, tuple[ResourcePoint, ...]]]:
    entries = []
    for entry in run.backends:
        resources = entry.resources
        if resources is None:
            continue
        summary = resources.summary or ResourceSummary()
        if not resources.series and all(getattr(summary, k) is None for k in _MEASURED):
            continue  # sampled nothing
        label = entry.label or entry.name or '?'
        entries.append((label, summary, resources.series))
    return entries


def _resources(run: RunResult, colours: Mapping[str, str]) -> str:
    """Per backend CPU, memory and GPU use, from run.json ``backends[i].resources``."""
    entries = _resource_entries(run)
    if not entries:
        return ''
    gpu = any(
        _num(getattr(s, k)) is not None
        for _, s, _ in entries
        for k in ('gpu_util_mean', 'gpu_mem_mb_peak', 'gpu_power_w_mean')
    )
    # private (anonymous) memory first, the mapped input apart; RSS for runs made before
    private = any(_num(s.private_mb_peak) is not None for _, s, _ in entries)
    memory = (
        [
            ('private_mb_peak', 'private peak MiB'),
            ('private_mb_mean', 'private mean MiB'),
            ('mapped_mb_peak', 'mapped input + libraries peak MiB'),
        ]
        if private
        else [('rss_mb_peak', 'RSS peak MiB'), ('rss_mb_mean', 'RSS mean MiB')]
    )
    head = ['backend', 'CPU % mean', 'CPU % max', *(title for _, title in memory)]
    if gpu:
        head += ['GPU util % mean', 'GPU mem peak MiB', 'GPU power W mean']
    head += ['samples', 'sampler cost']
    th = ''.join(
        f'<th>{_e(h)}</th>' if i == 0 else f'<th class="n">{_e(h)}</th>' for i, h in enumerate(head)
    )
    body = []
    gpu_names: list[str] = []
    for label, s, _ in entries:
        interval = _num(s.interval_s)
        cost = _num(s.overhead_ms_per_sample)
        share = _num(s.overhead_cpu_percent)
        cost_text = '–' if cost is None else f'{cost:.3f} ms/sample'
        if share is not None:
            cost_text += f', {share:.2f} % of a core'
        samples = _fmt_value(s.samples)
        if interval is not None:
            samples += f' every {interval:g} s'
        cells = [
            f'<td>{_swatch(colours, label)}{_e(label)}</td>',
            f'<td class="n">{_e(_fmt(s.cpu_percent_mean, 1))}</td>',
            f'<td class="n">{_e(_fmt(s.cpu_percent_max, 1))}</td>',
            *(f'<td class="n">{_e(_fmt(getattr(s, key), 1))}</td>' for key, _ in memory),
        ]
        if gpu:
            cells += [
                f'<td class="n">{_e(_fmt(s.gpu_util_mean, 1))}</td>',
                f'<td class="n">{_e(_fmt(s.gpu_mem_mb_peak, 0))}</td>',
                f'<td class="n">{_e(_fmt(s.gpu_power_w_mean, 1))}</td>',
            ]
            name = s.gpu_name
            if name and name not in gpu_names:
                gpu_names.append(name)
        cells += [f'<td class="n">{_e(samples)}</td>', f'<td class="n">{_e(cost_text)}</td>']
        body.append(f'<tr>{"".join(cells)}</tr>')
    note = (
        'Sampled in a background thread while each backend ran. CPU is this process (every '
        'thread) in % of one core, so more than 100 means several cores. '
        + (
            'Private memory is what the process allocated (RssAnon: resident, not backed by a '
            'file); mapped is the resident part of memory-mapped files, the input bag and the '
            'loaded libraries, which the kernel reads back from disk and can drop at any time, '
            'so a large bag is not a leak.'
            if private
            else 'RSS is its resident memory, the memory-mapped input included.'
        )
    )
    if gpu:
        note += ' GPU numbers are for the whole device' + (
            f' ({", ".join(gpu_names)})' if gpu_names else ''
        )
        note += ', all processes on it.'
    charts = []
    for key, title, y_label in _RESOURCE_CHARTS:
        if key == ('rss_mb' if private else 'private_mb'):
            continue
        series = []
        for label, _, points in entries:
            pairs = [
                (p.t_s, y)
                for p in points
                if _num(p.t_s) is not None and (y := _num(getattr(p, key))) is not None
            ]
            if pairs:
                series.append(
                    Series(
                        label,
                        colours.get(label, '#777'),
                        [x for x, _ in pairs],
                        [y for _, y in pairs],
                    ),
                )
        if series:
            longest = max(len(s.xs) for s in series)
            charts.append(
                line_chart(
                    series,
                    title=title,
                    x_label='time since the backend started (s)',
                    y_label=y_label,
                    mean_per_pixel=True,
                    note='Each point is the mean over the samples of one pixel column.'
                    if longest > _CHART_PIXELS
                    else '',
                    min_points=TREND_POINTS,
                ),
            )
    return (
        '<h2 id="resources">Resource use</h2>'
        f'<div class="table-wrap"><table><thead><tr>{th}</tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div><p class="muted">{_e(note)}</p>'
        + (f'<div class="charts">{"".join(charts)}</div>' if charts else '')
    )


# --------------------------------------------------------------------------- samples


def _sample_entries(run: RunResult) -> list[tuple[str, str, str]]:
    """(relative path, topic or '', caption) of each sample listed in run.json."""
    known: dict[str, str] = {}
    for source in run.inputs:
        for meta in source.topics:
            known[sample_relpath(source.index, meta.name)] = meta.name
    result = []
    for rel in run.outputs.samples if run.outputs is not None else ():
        topic = known.get(rel, '')
        caption = topic or PurePosixPath(rel).name
        if not topic and (mask := mask_of(rel)) is not None:  # beside its frame
            topic, caption = known.get(mask[0], ''), f'{mask[1]} mask'
        result.append((rel, topic, caption))
    return result


def _sample_data_uri(run_dir: Path, rel: str) -> str | None:
    pure = PurePosixPath(rel)
    if pure.is_absolute() or '..' in pure.parts or pure.suffix.lower() not in _IMAGE_TYPES:
        return None
    path = run_dir.joinpath(*pure.parts)
    try:
        if not path.resolve().is_relative_to(run_dir.resolve()) or not path.is_file():
            return None
        if path.stat().st_size > _MAX_SAMPLE_BYTES:
            return None
        data = path.read_bytes()
    except OSError:
        return None
    encoded = base64.b64encode(data).decode('ascii')
    return f'data:{_IMAGE_TYPES[pure.suffix.lower()]};base64,{encoded}'


def _samples(run: RunResult, run_dir: Path) -> str:
    entries = _sample_entries(run)
    if not entries:
        return ''
    groups: dict[str, list[str]] = {}
    for rel, topic, caption in entries:
        uri = _sample_data_uri(run_dir, rel)
        if uri is None:
            figure = (
                f'<figure><figcaption>{_e(caption)}: <code>{_e(rel)}</code> is missing or not '
                'an image in the run folder</figcaption></figure>'
            )
        else:
            figure = (
                f'<figure><img src="{uri}" alt="{_e(caption)}">'
                f'<figcaption>{_e(caption)}</figcaption></figure>'
            )
        groups.setdefault(topic, []).append(figure)
    parts = ['<h2 id="samples">Samples</h2>']
    for topic, figures in groups.items():
        if topic:
            parts.append(f'<h3><code>{_e(topic)}</code></h3>')
        parts.append(f'<div class="samples">{"".join(figures)}</div>')
    return ''.join(parts)


# --------------------------------------------------------------------------- details


def _details(run: RunResult) -> str:
    parts = ['<h2 id="details">Run details</h2>']
    if run.command:
        parts.append(f'<h3>Command</h3><pre>{_e(shlex.join(run.command))}</pre>')
    parts.append(
        _dl(
            [
                ('started', run.started_at),
                ('finished', run.finished_at),
                ('schema version', run.schema_version),
            ],
        ),
    )
    for entry in run.backends:
        info = json.dumps(to_json(entry.info), indent=2, ensure_ascii=False, sort_keys=True)
        parts.append(
            f'<details><summary>Backend {_e(entry.label or entry.name or "?")}'
            f'</summary><pre>{_pre(info)}</pre></details>',
        )
    for source in run.inputs:
        topics = json.dumps(to_json(source.topics), indent=2, ensure_ascii=False)
        parts.append(
            f'<details><summary>Input {_e(source.index)}: '
            f'<code>{_e(source.path or "?")}</code></summary>'
            f'<p>sha256 <code>{_e(source.sha256 or "?")}</code></p>'
            f'<pre>{_pre(topics)}</pre></details>',
        )
    env = json.dumps(to_json(run.environment), indent=2, ensure_ascii=False)
    parts.append(f'<details><summary>Environment</summary><pre>{_pre(env)}</pre></details>')
    return ''.join(parts)


# --------------------------------------------------------------------------- page


def _footer(run: RunResult) -> str:
    return (
        f'<footer>Generated by {_e(run.tool.name)} '
        f'{_e(run.tool.version)} from run.json (schema '
        f'{_e(run.schema_version)}), frames.csv and samples/. '
        'Self-contained: no external resources.</footer>'
    )


def _by_release(groups: Mapping[str, list[FrameRecord]]) -> dict[str, list[FrameRecord]]:
    # the passes of --repeat one after the other (results.repeats.one_timeline)
    return {b: one_timeline(rs) for b, rs in groups.items() if rs}


def render_html(data: RunData) -> str:
    """The report page of a loaded run folder."""
    run, frames = data.run, data.frames
    rows = _summary_rows(run, frames)
    backends = _backend_order(run, frames)
    for row in rows:
        backend = row.backend or '?'
        if backend not in backends:
            backends.append(backend)
    colours = {b: colour(i) for i, b in enumerate(backends)}
    topics = _topic_order(frames, rows)
    status = run.status
    body = [
        _header(run),
        _banner(run, frames, rows),
        headline_html(run, rows, frames),
        '<div class="cards">',
        _inputs_card(run),
        _environment_card(run.environment),
        _settings_card(run),
        '</div>',
        '<h2 id="summary">Summary</h2>',
        _summary_table(rows, colours),
        _accuracy_details(rows),
        recorded_latency_html(rows, frames, colours),
        tag_accuracy_html(rows),
        _plots(frames, rows, backends, topics, colours),
        _agreement(run, colours),
        _resources(run, colours),
        _samples(run, data.dir),
        _details(run),
        _footer(run),
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<title>replaybench report · {_e(status)}</title>'
        f'<style>{_CSS}</style></head><body><main>{"".join(body)}</main></body></html>\n'
    )


def render_report(run_dir: str | Path) -> Path:
    """Write ``run_dir/report.html`` (atomically) from the run folder and return its path."""
    data = load_run(run_dir)
    out = data.dir / 'report.html'
    write_text_atomic(out, render_html(data))
    return out


# --------------------------------------------------------------------------- peak.html

_OK = '#2e7d32'
_FAIL = '#c62828'


def load_peak(out_dir: str | Path) -> PeakResult:
    """Read ``out_dir/peak.json``; SourceError with the reason when it is not a readable one."""
    path = Path(out_dir) / 'peak.json'
    if not path.exists():
        msg = f'{out_dir}: no peak.json (not a replaybench peak folder, or the sweep did not end)'
        raise SourceError(msg)
    return read_peak_result(path)


def _fmt_hz(value: Any) -> str:
    number = _num(value)
    return '–' if number is None else f'{number:g} Hz'


def _peak_verdict(peak: PeakResult) -> str:
    settings = peak.settings
    max_drop = _num(settings.max_drop)
    bound = _num(settings.p99_bound_ms)
    rule = f'at most {100 * (max_drop or 0):g} % of the frames dropped'
    if bound is not None:
        rule += f' and p99 latency at most {bound:g} ms'
    best = _num(peak.peak_hz)
    failing = _num(peak.first_failing_hz)
    if best is None:
        return (
            f'<p><strong>No tested rate passed</strong>, down to {_e(_fmt_hz(settings.min_hz))} '
            f'({_e(rule)}).</p>'
        )
    text = (
        f'<p><strong>Peak sustainable rate: {_e(_fmt_hz(best))}</strong> per topic — the highest '
        f'tested rate with {_e(rule)}.'
    )
    if failing is not None:
        text += f' The lowest failing rate tested was {_e(_fmt_hz(failing))}'
        resolution = failing - best
        text += f' (resolution {resolution:.3g} Hz).' if resolution > 0 else '.'
    if peak.limit_reached:
        text += ' Every rate up to the search limit passed: the backend may keep up with more.'
    return text + '</p>'


def _peak_trials(peak: PeakResult) -> str:
    best = _num(peak.peak_hz)
    body = []
    for number, trial in enumerate(peak.trial_rows, 1):
        ok = trial.ok
        rate = _num(trial.rate_hz)
        marker = ' class="peak"' if best is not None and rate == best else ''
        verdict = f'<span style="color:{_OK if ok else _FAIL}">{"pass" if ok else "fail"}</span>'
        body.append(
            f'<tr{marker}><td class="n">{number}</td>'
            f'<td class="n">{_e(_fmt_hz(rate))}</td>'
            f'<td class="n">{_e(_fmt_value(trial.frames))}</td>'
            f'<td class="n">{_e(_fmt_value(trial.dropped))}</td>'
            f'<td class="n">{_e(_fmt_frac(trial.drop_fraction))}</td>'
            f'<td class="n">{_e(_fmt_ms(trial.p99_ms))}</td>'
            f'<td>{verdict}</td><td><code>{_e(trial.run_dir)}</code></td></tr>',
        )
    return (
        '<div class="table-wrap"><table><thead><tr><th class="n">#</th><th class="n">rate</th>'
        '<th class="n">frames</th><th class="n">dropped</th><th class="n">dropped %</th>'
        '<th class="n">p99 ms</th><th>verdict</th><th>run folder</th></tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>'
        '<p class="muted">Trials in the order they ran. Frames and drops count from the end of '
        'the warm-up on; p99 is over the measured frames.</p>'
    )


def _peak_charts(peak: PeakResult) -> str:
    trials = sorted((t for t in peak.trial_rows if _num(t.rate_hz)), key=lambda t: t.rate_hz)
    if not trials:
        return ''
    settings = peak.settings
    best = _num(peak.peak_hz)
    rules_x = [Rule('x', best, f'peak {best:g} Hz', _OK)] if best is not None else []
    charts = []
    for key, title, y_label, limit, scale in (
        ('drop_fraction', 'Dropped frames vs rate', 'dropped (%)', settings.max_drop, 100.0),
        ('p99_ms', 'p99 latency vs rate', 'p99 latency (ms)', settings.p99_bound_ms, 1.0),
    ):
        points: list[tuple[float, float, bool]] = []
        for t in trials:
            x, y = _num(t.rate_hz), _num(getattr(t, key))
            if x is not None and y is not None:
                points.append((x, y * scale, t.ok))
        if not points:
            continue
        series = [Series('all trials', '#999', [p[0] for p in points], [p[1] for p in points])]
        for name, fill, wanted in (('passed', _OK, True), ('failed', _FAIL, False)):
            chosen = [p for p in points if p[2] is wanted]
            if chosen:
                series.append(
                    Series(name, fill, [p[0] for p in chosen], [p[1] for p in chosen], 'dots'),
                )
        rules = list(rules_x)
        if limit is not None and _num(limit) is not None:
            label = f'max {limit * scale:g} %' if key == 'drop_fraction' else f'bound {limit:g} ms'
            rules.append(Rule('y', limit * scale, label, _FAIL))
        charts.append(
            line_chart(
                series,
                title=title,
                x_label='input rate per topic (Hz)',
                y_label=y_label,
                x_range=(0.0, max(p[0] for p in points) * 1.05),
                rules=rules,
            ),
        )
    return f'<div class="charts">{"".join(charts)}</div>'


def render_peak_html(peak: PeakResult) -> str:
    """The page of a peak.json (``replaybench peak``)."""
    status = peak.status
    tool, source, start = peak.tool, peak.input, peak.start
    meta = [
        f'<span class="badge {_e(status)}">{_e(status)}</span>',
        f'backend {_e(peak.backend or "?")}',
        f'started {_e(peak.started_at or "?")}',
    ]
    wall = _num(peak.wall_s)
    if wall is not None:
        meta.append(f'wall time {wall:.1f} s')
    meta.append(f'{_e(tool.name)} {_e(tool.version or "?")}')
    items: list[tuple[str, Any]] = [
        ('input', source.path or None),
        ('sha256', source.sha256),
        ('start rate', f'{_fmt_hz(start.hz)} (from the {start.source or "?"})'),
        ('max-rate probe', f'{_fmt(start.probe_fps)} frames/s per topic'),
        ('recorded rate', _fmt_hz(start.recorded_hz)),
    ]
    items += list(to_json(peak.settings).items())
    banner = ''
    if status == 'interrupted':
        banner = (
            '<div class="banner" role="alert"><strong>Warnings</strong><ul><li>The sweep was '
            'interrupted: the result covers only the trials that finished.</li></ul></div>'
        )
    footer = (
        f'<footer>Generated by {_e(tool.name)} '
        f'{_e(tool.version)} from peak.json (schema '
        f'{_e(peak.schema_version)}). Self-contained: no external resources.'
        '</footer>'
    )
    body = [
        f'<header><h1>replaybench peak rate</h1><p class="meta">{" · ".join(meta)}</p></header>',
        banner,
        _peak_verdict(peak),
        '<div class="cards">',
        f'<div class="card"><h3>Sweep</h3>{_dl(items)}</div>',
        _environment_card(peak.environment),
        '</div>',
        '<h2 id="trials">Trials</h2>',
        _peak_trials(peak),
        _peak_charts(peak),
        f'<h3>Command</h3><pre>{_e(shlex.join(peak.command))}</pre>' if peak.command else '',
        footer,
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<title>replaybench peak rate · {_e(peak.backend or "?")}</title>'
        f'<style>{_CSS}</style></head><body><main>{"".join(body)}</main></body></html>\n'
    )


def render_peak_report(out_dir: str | Path) -> Path:
    """Write ``out_dir/peak.html`` (atomically) from ``out_dir/peak.json`` and return its path."""
    peak = load_peak(out_dir)
    out = Path(out_dir) / 'peak.html'
    write_text_atomic(out, render_peak_html(peak))
    return out
