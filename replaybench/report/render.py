"""report.html: one self-contained page (inline CSS, inline SVG, embedded images) per run folder."""

from __future__ import annotations

import base64
import json
import math
import shlex
from html import escape
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any

from replaybench.errors import SourceError
from replaybench.report.headline import headline_html
from replaybench.report.samples import sample_relpath
from replaybench.report.svg import (
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
from replaybench.results.runfile import load_run, write_text_atomic
from replaybench.results.stats import summarize, summary_json
from replaybench.textsafe import visible, visible_lines

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    from replaybench.results.records import FrameRecord
    from replaybench.results.runfile import RunData

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


def _backend_order(run: Mapping[str, Any], frames: Sequence[FrameRecord]) -> list[str]:
    order: list[str] = []
    for entry in _list(run.get('backends')):
        entry = _dict(entry)
        label = entry.get('label') or entry.get('name')
        if isinstance(label, str) and label not in order:
            order.append(label)
    for record in frames:
        if record.backend not in order:
            order.append(record.backend)
    return order


def _topic_order(frames: Sequence[FrameRecord], rows: Sequence[Mapping[str, Any]]) -> list[str]:
    order: list[str] = []
    for topic in [r.topic for r in frames] + [str(r.get('topic')) for r in rows]:
        if topic not in order:
            order.append(topic)
    return order


def _summary_rows(run: Mapping[str, Any], frames: Sequence[FrameRecord]) -> list[dict[str, Any]]:
    rows = [r for r in _list(run.get('summary')) if isinstance(r, dict)]
    if rows:
        return rows
    return [summary_json(s) for s in summarize(frames)]


# --------------------------------------------------------------------------- header


def _header(run: Mapping[str, Any]) -> str:
    status = str(run.get('status', 'unknown'))
    tool = _dict(run.get('tool'))
    meta = [
        f'<span class="badge {_e(status)}">{_e(status)}</span>',
        f'started {_e(run.get("started_at", "?"))}',
    ]
    wall = _num(run.get('wall_s'))
    if wall is not None:
        meta.append(f'wall time {wall:.1f} s')
    meta.append(f'{_e(tool.get("name", "replaybench"))} {_e(tool.get("version", "?"))}')
    return f'<header><h1>replaybench report</h1><p class="meta">{" · ".join(meta)}</p></header>'


def _banner(run: Mapping[str, Any], frames: Sequence[FrameRecord]) -> str:
    items: list[str] = []
    status = run.get('status')
    if status == 'interrupted':
        items.append(
            'The run was interrupted: the numbers cover only the frames processed before it '
            'stopped.',
        )
    elif status not in (None, 'complete'):
        items.append(f'The run ended with status {_e(status)}.')
    for entry in _list(run.get('inputs')):
        entry = _dict(entry)
        path = _e(entry.get('path', '?'))
        if entry.get('truncated'):
            items.append(
                f'Input <code>{path}</code> is truncated: only its complete messages were '
                'replayed.',
            )
        for warning in _list(entry.get('warnings')):
            items.append(f'<code>{path}</code>: {_e(warning)}')
    skipped = {str(k): v for k, v in _dict(run.get('skipped')).items()}
    n_skipped = sum(1 for r in frames if r.status == 'skipped')
    if skipped or n_skipped:
        reasons = ''.join(
            f'<li>{_e(reason)}: {_e(count)}</li>' for reason, count in sorted(skipped.items())
        )
        counted = sum(v for v in skipped.values() if _int(v) is not None)
        total = counted or n_skipped
        items.append(
            f'{total} frame(s) were skipped because they could not be decoded'
            + (f'<ul>{reasons}</ul>' if reasons else '.'),
        )
    if not items:
        return ''
    body = ''.join(f'<li>{item}</li>' for item in items)
    return f'<div class="banner" role="alert"><strong>Warnings</strong><ul>{body}</ul></div>'


def _inputs_card(run: Mapping[str, Any]) -> str:
    rows = []
    for entry in _list(run.get('inputs')):
        entry = _dict(entry)
        sha = str(entry.get('sha256') or '')
        topics = ', '.join(str(_dict(t).get('name', '?')) for t in _list(entry.get('topics')))
        flags = ' (truncated)' if entry.get('truncated') else ''
        rows.append(
            f'<tr><td class="n">{_e(entry.get("index", ""))}</td>'
            f'<td><code>{_e(entry.get("path", "?"))}</code>{_e(flags)}'
            f'<br><span class="muted">{_e(topics)}</span></td>'
            f'<td>{_e(entry.get("format", ""))}</td>'
            f'<td class="n">{_e(_fmt_bytes(entry.get("size_bytes")))}</td>'
            f'<td><code title="{_e(sha)}">{_e(sha[:12])}</code></td></tr>',
        )
    table = (
        '<table><thead><tr><th class="n">#</th><th>path / topics</th><th>format</th>'
        f'<th class="n">size</th><th>sha256</th></tr></thead><tbody>{"".join(rows)}</tbody>'
        '</table>'
    )
    return f'<div class="card"><h3>Inputs</h3>{table}</div>'


def _environment_card(run: Mapping[str, Any]) -> str:
    env = _dict(run.get('environment'))
    cpu = _dict(env.get('cpu'))
    os_info = _dict(env.get('os'))
    python = _dict(env.get('python'))
    packages = _dict(env.get('packages'))
    opencv = _dict(packages.get('opencv'))
    gpus = [
        f'{_dict(g).get("name", "?")} ({_dict(g).get("memory_total", "?")}, '
        f'driver {_dict(g).get("driver_version", "?")})'
        for g in _list(env.get('gpus'))
    ]
    versions = [
        f'{name} {value}'
        for name, value in packages.items()
        if name != 'opencv' and isinstance(value, str)
    ]
    if opencv.get('version'):
        versions.append(f'opencv {opencv["version"]} ({opencv.get("threads", "?")} threads)')
    cores = cpu.get('logical_cores')
    usable = cpu.get('usable_cores')
    core_text = f'{cores}' + (f' ({usable} usable)' if usable not in (None, cores) else '')
    load = _list(env.get('load_average'))
    items: list[tuple[str, Any]] = [
        ('CPU', cpu.get('model')),
        ('cores', core_text),
        ('governor', cpu.get('governor')),
        ('memory', _fmt_bytes(env.get('memory_total_bytes'))),
        ('GPUs', '; '.join(gpus) if gpus else 'none found'),
        ('OS', os_info.get('platform') or os_info.get('system')),
        ('Python', f'{python.get("implementation", "")} {python.get("version", "")}'.strip()),
        ('packages', ', '.join(versions)),
        ('load average', ' '.join(_fmt_value(v) for v in load) if load else None),
    ]
    return f'<div class="card"><h3>Machine</h3>{_dl(items)}</div>'


def _settings_card(run: Mapping[str, Any]) -> str:
    settings = _dict(run.get('settings'))
    backends = []
    for entry in _list(run.get('backends')):
        entry = _dict(entry)
        name, label = entry.get('name', '?'), entry.get('label', '')
        backends.append(f'{label} ({name})' if label and label != name else str(name))
    items: list[tuple[str, Any]] = [('backends', ', '.join(backends) or None)]
    items += [(str(k), v) for k, v in settings.items()]
    return f'<div class="card"><h3>Settings</h3>{_dl(items)}</div>'


# --------------------------------------------------------------------------- summary


def _summary_table(rows: Sequence[Mapping[str, Any]], colours: Mapping[str, str]) -> str:
    accuracy = any(isinstance(r.get('accuracy'), dict) for r in rows) or any(
        r.get('map50') is not None for r in rows
    )
    head = [
        ('backend', ''),
        ('topic', ''),
        ('measured', 'n'),
        ('dropped', 'n'),
        ('skipped', 'n'),
        ('FPS', 'n'),
        ('p50 ms', 'n'),
        ('p95 ms', 'n'),
        ('p99 ms', 'n'),
        ('max ms', 'n'),
        ('jitter ms', 'n'),
        ('det/frame', 'n'),
    ]
    if accuracy:
        head += [('P@0.5', 'n'), ('R@0.5', 'n'), ('mAP@0.5', 'n'), ('mAP@0.5:0.95', 'n')]
    th = ''.join(
        f'<th class="{c}">{_e(name)}</th>' if c else f'<th>{_e(name)}</th>' for name, c in head
    )
    body = []
    for row in rows:
        backend = str(row.get('backend', '?'))
        swatch = f'<span class="swatch" style="background:{colours.get(backend, "#777")}"></span>'
        cells = [
            f'<td>{swatch}{_e(backend)}</td>',
            f'<td><code>{_e(row.get("topic", "?"))}</code></td>',
            f'<td class="n">{_e(_fmt_value(row.get("measured")))}</td>',
            f'<td class="n">{_e(_fmt_value(row.get("dropped")))}</td>',
            f'<td class="n">{_e(_fmt_value(row.get("skipped")))}</td>',
            f'<td class="n">{_e(_fmt_fps(row.get("throughput_fps")))}</td>',
        ]
        for key in ('latency_ms_p50', 'latency_ms_p95', 'latency_ms_p99', 'latency_ms_max'):
            cells.append(f'<td class="n">{_e(_fmt_ms(row.get(key)))}</td>')
        cells.append(f'<td class="n">{_e(_fmt_ms(row.get("jitter_ms")))}</td>')
        cells.append(f'<td class="n">{_e(_fmt(row.get("detections_per_frame")))}</td>')
        if accuracy:
            acc = _dict(row.get('accuracy'))
            for key in ('precision50', 'recall50', 'map50', 'map50_95'):
                value = acc.get(key, row.get(key))
                cells.append(f'<td class="n">{_e(_fmt(value, 3))}</td>')
        body.append(f'<tr>{"".join(cells)}</tr>')
    return (
        f'<div class="table-wrap"><table id="summary-table"><thead><tr>{th}</tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>'
        '<p class="muted">Statistics cover measured frames only (processed, after warm-up). '
        'FPS: measured frames per second of processing window; jitter: mean absolute '
        'difference of consecutive latencies.</p>'
    )


def _accuracy_details(rows: Sequence[Mapping[str, Any]]) -> str:
    parts = []
    for row in rows:
        acc = _dict(row.get('accuracy'))
        ap50, ap50_95 = _dict(acc.get('ap50')), _dict(acc.get('ap50_95'))
        if not ap50 and not ap50_95:
            continue
        labels = sorted(set(ap50) | set(ap50_95))
        body = ''.join(
            f'<tr><td>{_e(label)}</td><td class="n">{_e(_fmt(ap50.get(label), 3))}</td>'
            f'<td class="n">{_e(_fmt(ap50_95.get(label), 3))}</td></tr>'
            for label in labels
        )
        counts = ', '.join(
            f'{k} {acc[k]}' for k in ('frames', 'n_gt', 'n_det') if _int(acc.get(k)) is not None
        )
        parts.append(
            f'<h3>{_e(row.get("backend", "?"))} · <code>{_e(row.get("topic", "?"))}</code></h3>'
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
    )


def _group_label(row: Mapping[str, Any], many_topics: bool) -> str:
    backend = str(row.get('backend', '?'))
    return f'{backend} · {row.get("topic", "?")}' if many_topics else backend


def _throughput_chart(
    rows: Sequence[Mapping[str, Any]],
    colours: Mapping[str, str],
    many_topics: bool,
) -> str:
    return bar_chart(
        [_group_label(r, many_topics) for r in rows],
        [_num(r.get('throughput_fps')) for r in rows],
        [colours.get(str(r.get('backend')), '#777') for r in rows],
        title='Throughput (measured frames per second)',
        x_label='frames per second',
    )


def _stage_chart(rows: Sequence[Mapping[str, Any]], many_topics: bool) -> str:
    segments = []
    for key, name, fill in _STAGES:
        values = [_num(r.get(key)) for r in rows]
        if not any(v for v in values):
            continue
        segments.append(Segment(name, fill, values))
    rest: list[float | None] = []
    for r in rows:
        mean = _num(r.get('latency_ms_mean'))
        parts = [_num(r.get(key)) for key, _, _ in _STAGES]
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
    rows: Sequence[Mapping[str, Any]],
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
    parts.append('<h2 id="detections">Detections</h2>')
    for topic in topics:
        groups = _by_release(by_topic[topic])
        if groups:
            parts.append(
                f'<div class="charts">{_detections_timeline(topic, groups, colours)}</div>'
            )
    return ''.join(parts)


# --------------------------------------------------------------------------- agreement


def _frame_name(key: Any, single_input: bool) -> str:
    if isinstance(key, list | tuple) and len(key) == 2:
        index, seq = key
        return f'#{seq}' if single_input else f'{index}:#{seq}'
    return str(key)


def _fmt_frac(value: Any) -> str:
    number = _num(value)
    return '–' if number is None else f'{100 * number:.1f} %'


def _swatch(colours: Mapping[str, str], backend: str) -> str:
    return f'<span class="swatch" style="background:{_e(colours.get(backend, "#777"))}"></span>'


def _agreement(run: Mapping[str, Any], colours: Mapping[str, str]) -> str:
    """Agreement between backends per topic, from run.json ``agreement``."""
    entries = [_dict(e) for e in _list(run.get('agreement')) if isinstance(e, dict)]
    if not entries:
        return ''
    single_input = len(_list(run.get('inputs'))) <= 1
    threshold = _num(_dict(run.get('settings')).get('agreement_iou')) or 0.5
    by_topic: dict[str, list[dict[str, Any]]] = {}
    for entry in entries:
        by_topic.setdefault(str(entry.get('topic', '?')), []).append(entry)
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
            a, b = str(entry.get('backend_a', '?')), str(entry.get('backend_b', '?'))
            frames = [_frame_name(k, single_input) for k in _list(entry.get('disagreeing_frames'))]
            shown = ', '.join(frames[:6]) + (f' … (+{len(frames) - 6})' if len(frames) > 6 else '')
            body.append(
                f'<tr><td>{_swatch(colours, a)}{_e(a)} / {_swatch(colours, b)}{_e(b)}</td>'
                f'<td class="n">{_e(_fmt_value(entry.get("frames")))}</td>'
                f'<td class="n">{_e(_fmt_value(entry.get("n_a")))}</td>'
                f'<td class="n">{_e(_fmt_value(entry.get("n_b")))}</td>'
                f'<td class="n">{_e(_fmt_value(entry.get("matched")))}</td>'
                f'<td class="n">{_e(_fmt_frac(entry.get("matched_frac_a")))}</td>'
                f'<td class="n">{_e(_fmt_frac(entry.get("matched_frac_b")))}</td>'
                f'<td class="n">{_e(_fmt(entry.get("mean_iou"), 3))}</td>'
                f'<td class="n">{_e(_fmt(entry.get("mean_abs_score_diff"), 3))}</td>'
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


def _resource_entries(run: Mapping[str, Any]) -> list[tuple[str, dict[str, Any], list[Any]]]:
    entries = []
    for entry in _list(run.get('backends')):
        entry = _dict(entry)
        resources = _dict(entry.get('resources'))
        summary = _dict(resources.get('summary'))
        series = [p for p in _list(resources.get('series')) if isinstance(p, dict)]
        if not summary and not series:
            continue
        label = str(entry.get('label') or entry.get('name') or '?')
        entries.append((label, summary, series))
    return entries


def _resources(run: Mapping[str, Any], colours: Mapping[str, str]) -> str:
    """Per backend CPU, memory and GPU use, from run.json ``backends[i].resources``."""
    entries = _resource_entries(run)
    if not entries:
        return ''
    gpu = any(
        _num(s.get(k)) is not None
        for _, s, _ in entries
        for k in ('gpu_util_mean', 'gpu_mem_mb_peak', 'gpu_power_w_mean')
    )
    # private (anonymous) memory first, the mapped input apart; RSS for runs made before
    private = any(_num(s.get('private_mb_peak')) is not None for _, s, _ in entries)
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
        interval = _num(s.get('interval_s'))
        cost = _num(s.get('overhead_ms_per_sample'))
        share = _num(s.get('overhead_cpu_percent'))
        cost_text = '–' if cost is None else f'{cost:.3f} ms/sample'
        if share is not None:
            cost_text += f', {share:.2f} % of a core'
        samples = _fmt_value(s.get('samples'))
        if interval is not None:
            samples += f' every {interval:g} s'
        cells = [
            f'<td>{_swatch(colours, label)}{_e(label)}</td>',
            f'<td class="n">{_e(_fmt(s.get("cpu_percent_mean"), 1))}</td>',
            f'<td class="n">{_e(_fmt(s.get("cpu_percent_max"), 1))}</td>',
            *(f'<td class="n">{_e(_fmt(s.get(key), 1))}</td>' for key, _ in memory),
        ]
        if gpu:
            cells += [
                f'<td class="n">{_e(_fmt(s.get("gpu_util_mean"), 1))}</td>',
                f'<td class="n">{_e(_fmt(s.get("gpu_mem_mb_peak"), 0))}</td>',
                f'<td class="n">{_e(_fmt(s.get("gpu_power_w_mean"), 1))}</td>',
            ]
            name = s.get('gpu_name')
            if isinstance(name, str) and name and name not in gpu_names:
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
            xs = [_num(p.get('t_s')) for p in points]
            ys = [_num(p.get(key)) for p in points]
            pairs = [(x, y) for x, y in zip(xs, ys, strict=True) if x is not None and y is not None]
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
                ),
            )
    return (
        '<h2 id="resources">Resource use</h2>'
        f'<div class="table-wrap"><table><thead><tr>{th}</tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div><p class="muted">{_e(note)}</p>'
        + (f'<div class="charts">{"".join(charts)}</div>' if charts else '')
    )


# --------------------------------------------------------------------------- samples


def _sample_entries(run: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    """(relative path, topic or '', caption) of each sample listed in run.json."""
    known: dict[str, str] = {}
    for entry in _list(run.get('inputs')):
        entry = _dict(entry)
        index = _int(entry.get('index'))
        if index is None:
            continue
        for topic in _list(entry.get('topics')):
            name = _dict(topic).get('name')
            if isinstance(name, str):
                known[sample_relpath(index, name)] = name
    result = []
    for item in _list(_dict(run.get('outputs')).get('samples')):
        if isinstance(item, str):
            rel, topic, caption = item, known.get(item, ''), ''
        elif isinstance(item, dict) and isinstance(item.get('path'), str):
            rel = item['path']
            topic = str(item.get('topic') or known.get(rel, ''))
            caption = str(item.get('title') or '')
        else:
            continue
        result.append((rel, topic, caption or topic or PurePosixPath(rel).name))
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


def _samples(run: Mapping[str, Any], run_dir: Path) -> str:
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


def _details(run: Mapping[str, Any]) -> str:
    command = [str(c) for c in _list(run.get('command'))]
    backends = _list(run.get('backends'))
    env = _dict(run.get('environment'))
    parts = ['<h2 id="details">Run details</h2>']
    if command:
        parts.append(f'<h3>Command</h3><pre>{_e(shlex.join(command))}</pre>')
    parts.append(
        _dl(
            [
                ('started', run.get('started_at')),
                ('finished', run.get('finished_at')),
                ('schema version', run.get('schema_version')),
            ],
        ),
    )
    for entry in backends:
        entry = _dict(entry)
        info = json.dumps(entry.get('info', {}), indent=2, ensure_ascii=False, sort_keys=True)
        parts.append(
            f'<details><summary>Backend {_e(entry.get("label") or entry.get("name", "?"))}'
            f'</summary><pre>{_pre(info)}</pre></details>',
        )
    for entry in _list(run.get('inputs')):
        entry = _dict(entry)
        topics = json.dumps(entry.get('topics', []), indent=2, ensure_ascii=False)
        parts.append(
            f'<details><summary>Input {_e(entry.get("index", "?"))}: '
            f'<code>{_e(entry.get("path", "?"))}</code></summary>'
            f'<p>sha256 <code>{_e(entry.get("sha256", "?"))}</code></p>'
            f'<pre>{_pre(topics)}</pre></details>',
        )
    parts.append(
        '<details><summary>Environment</summary>'
        f'<pre>{_pre(json.dumps(env, indent=2, ensure_ascii=False))}</pre></details>',
    )
    return ''.join(parts)


# --------------------------------------------------------------------------- page


def _footer(run: Mapping[str, Any]) -> str:
    tool = _dict(run.get('tool'))
    return (
        f'<footer>Generated by {_e(tool.get("name", "replaybench"))} '
        f'{_e(tool.get("version", ""))} from run.json (schema '
        f'{_e(run.get("schema_version", "?"))}), frames.csv and samples/. '
        'Self-contained: no external resources.</footer>'
    )


def _by_release(groups: Mapping[str, list[FrameRecord]]) -> dict[str, list[FrameRecord]]:
    return {b: sorted(rs, key=lambda r: r.release_s) for b, rs in groups.items() if rs}


def render_html(data: RunData) -> str:
    """The report page of a loaded run folder."""
    run, frames = data.run, data.frames
    rows = _summary_rows(run, frames)
    backends = _backend_order(run, frames)
    for row in rows:
        backend = str(row.get('backend', '?'))
        if backend not in backends:
            backends.append(backend)
    colours = {b: colour(i) for i, b in enumerate(backends)}
    topics = _topic_order(frames, rows)
    status = str(run.get('status', 'unknown'))
    body = [
        _header(run),
        _banner(run, frames),
        headline_html(run, rows, frames),
        '<div class="cards">',
        _inputs_card(run),
        _environment_card(run),
        _settings_card(run),
        '</div>',
        '<h2 id="summary">Summary</h2>',
        _summary_table(rows, colours),
        _accuracy_details(rows),
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

#: Version of the peak.json layout (written by ``replaybench.replay.peak``).
PEAK_SCHEMA_VERSION = 1

_OK = '#2e7d32'
_FAIL = '#c62828'


def load_peak(out_dir: str | Path) -> dict[str, Any]:
    """Read ``out_dir/peak.json``; SourceError with the reason when it is not a readable one."""
    path = Path(out_dir) / 'peak.json'
    try:
        peak = json.loads(path.read_text(encoding='utf-8'))
    except FileNotFoundError:
        msg = f'{out_dir}: no peak.json (not a replaybench peak folder, or the sweep did not end)'
        raise SourceError(msg) from None
    except (OSError, UnicodeDecodeError) as err:
        msg = f'{path}: cannot read: {err}'
        raise SourceError(msg) from None
    except json.JSONDecodeError as err:
        msg = f'{path}: invalid JSON at line {err.lineno} column {err.colno}: {err.msg}'
        raise SourceError(msg) from None
    version = peak.get('schema_version') if isinstance(peak, dict) else None
    if not isinstance(peak, dict) or peak.get('kind') != 'peak':
        msg = f'{path}: not a peak.json (expected an object with "kind": "peak")'
        raise SourceError(msg)
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        msg = f'{path}: missing or invalid schema_version {version!r}'
        raise SourceError(msg)
    if version > PEAK_SCHEMA_VERSION:
        msg = (
            f'{path}: schema_version {version} is newer than this replaybench supports '
            f'({PEAK_SCHEMA_VERSION}); upgrade replaybench to read it'
        )
        raise SourceError(msg)
    return peak


def _fmt_hz(value: Any) -> str:
    number = _num(value)
    return '–' if number is None else f'{number:g} Hz'


def _peak_verdict(peak: Mapping[str, Any]) -> str:
    settings = _dict(peak.get('settings'))
    max_drop = _num(settings.get('max_drop'))
    bound = _num(settings.get('p99_bound_ms'))
    rule = f'at most {100 * (max_drop or 0):g} % of the frames dropped'
    if bound is not None:
        rule += f' and p99 latency at most {bound:g} ms'
    best = _num(peak.get('peak_hz'))
    failing = _num(peak.get('first_failing_hz'))
    if best is None:
        lowest = _num(settings.get('min_hz'))
        return (
            f'<p><strong>No tested rate passed</strong>, down to {_e(_fmt_hz(lowest))} '
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
    if peak.get('limit_reached'):
        text += ' Every rate up to the search limit passed: the backend may keep up with more.'
    return text + '</p>'


def _peak_trials(peak: Mapping[str, Any]) -> str:
    trials = [_dict(t) for t in _list(peak.get('trials'))]
    best = _num(peak.get('peak_hz'))
    body = []
    for number, trial in enumerate(trials, 1):
        ok = bool(trial.get('ok'))
        rate = _num(trial.get('rate_hz'))
        marker = ' class="peak"' if best is not None and rate == best else ''
        verdict = f'<span style="color:{_OK if ok else _FAIL}">{"pass" if ok else "fail"}</span>'
        body.append(
            f'<tr{marker}><td class="n">{number}</td>'
            f'<td class="n">{_e(_fmt_hz(rate))}</td>'
            f'<td class="n">{_e(_fmt_value(trial.get("frames")))}</td>'
            f'<td class="n">{_e(_fmt_value(trial.get("dropped")))}</td>'
            f'<td class="n">{_e(_fmt_frac(trial.get("drop_fraction")))}</td>'
            f'<td class="n">{_e(_fmt_ms(trial.get("p99_ms")))}</td>'
            f'<td>{verdict}</td><td><code>{_e(trial.get("run_dir", ""))}</code></td></tr>',
        )
    return (
        '<div class="table-wrap"><table><thead><tr><th class="n">#</th><th class="n">rate</th>'
        '<th class="n">frames</th><th class="n">dropped</th><th class="n">dropped %</th>'
        '<th class="n">p99 ms</th><th>verdict</th><th>run folder</th></tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>'
        '<p class="muted">Trials in the order they ran. Frames and drops count from the end of '
        'the warm-up on; p99 is over the measured frames.</p>'
    )


def _peak_charts(peak: Mapping[str, Any]) -> str:
    trials = sorted(
        (t for t in (_dict(x) for x in _list(peak.get('trials'))) if _num(t.get('rate_hz'))),
        key=lambda t: _num(t.get('rate_hz')) or 0.0,
    )
    if not trials:
        return ''
    settings = _dict(peak.get('settings'))
    best = _num(peak.get('peak_hz'))
    rules_x = [Rule('x', best, f'peak {best:g} Hz', _OK)] if best is not None else []
    charts = []
    for key, title, y_label, bound, scale in (
        ('drop_fraction', 'Dropped frames vs rate', 'dropped (%)', 'max_drop', 100.0),
        ('p99_ms', 'p99 latency vs rate', 'p99 latency (ms)', 'p99_bound_ms', 1.0),
    ):
        points: list[tuple[float, float, bool]] = []
        for t in trials:
            x, y = _num(t.get('rate_hz')), _num(t.get(key))
            if x is not None and y is not None:
                points.append((x, y * scale, bool(t.get('ok'))))
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
        limit = _num(settings.get(bound))
        if limit is not None:
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


def render_peak_html(peak: Mapping[str, Any]) -> str:
    """The page of a peak.json (``replaybench peak``)."""
    status = str(peak.get('status', 'unknown'))
    tool = _dict(peak.get('tool'))
    source = _dict(peak.get('input'))
    start = _dict(peak.get('start'))
    meta = [
        f'<span class="badge {_e(status)}">{_e(status)}</span>',
        f'backend {_e(peak.get("backend", "?"))}',
        f'started {_e(peak.get("started_at", "?"))}',
    ]
    wall = _num(peak.get('wall_s'))
    if wall is not None:
        meta.append(f'wall time {wall:.1f} s')
    meta.append(f'{_e(tool.get("name", "replaybench"))} {_e(tool.get("version", "?"))}')
    settings = _dict(peak.get('settings'))
    items: list[tuple[str, Any]] = [
        ('input', source.get('path')),
        ('sha256', source.get('sha256')),
        ('start rate', f'{_fmt_hz(start.get("hz"))} (from the {start.get("from", "?")})'),
        ('max-rate probe', f'{_fmt(start.get("probe_fps"))} frames/s per topic'),
        ('recorded rate', _fmt_hz(start.get('recorded_hz'))),
    ]
    items += [(str(k), v) for k, v in settings.items()]
    banner = ''
    if status == 'interrupted':
        banner = (
            '<div class="banner" role="alert"><strong>Warnings</strong><ul><li>The sweep was '
            'interrupted: the result covers only the trials that finished.</li></ul></div>'
        )
    command = [str(c) for c in _list(peak.get('command'))]
    footer = (
        f'<footer>Generated by {_e(tool.get("name", "replaybench"))} '
        f'{_e(tool.get("version", ""))} from peak.json (schema '
        f'{_e(peak.get("schema_version", "?"))}). Self-contained: no external resources.'
        '</footer>'
    )
    body = [
        f'<header><h1>replaybench peak rate</h1><p class="meta">{" · ".join(meta)}</p></header>',
        banner,
        _peak_verdict(peak),
        '<div class="cards">',
        f'<div class="card"><h3>Sweep</h3>{_dl(items)}</div>',
        _environment_card(peak),
        '</div>',
        '<h2 id="trials">Trials</h2>',
        _peak_trials(peak),
        _peak_charts(peak),
        f'<h3>Command</h3><pre>{_e(shlex.join(command))}</pre>' if command else '',
        footer,
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<title>replaybench peak rate · {_e(peak.get("backend", "?"))}</title>'
        f'<style>{_CSS}</style></head><body><main>{"".join(body)}</main></body></html>\n'
    )


def render_peak_report(out_dir: str | Path) -> Path:
    """Write ``out_dir/peak.html`` (atomically) from ``out_dir/peak.json`` and return its path."""
    peak = load_peak(out_dir)
    out = Path(out_dir) / 'peak.html'
    write_text_atomic(out, render_peak_html(peak))
    return out
