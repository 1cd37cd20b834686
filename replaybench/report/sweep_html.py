"""sweep.html: one self-contained page (inline CSS, no scripts) for a sweep.json record.

The matrix has a row per input and a column per backend and parameter combination; each cell
shows FPS, p50 and p99 latency with their 95 % intervals, the tasks' main figures the sweep
keeps (``MetricSpec.main`` and ``sweep``: the boxes' mAP@0.5 in every cell, another task's
where the cell has it) and where it ran, links to the cell's report.html, and marks the best FPS
(and the best of each main figure) of its row.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.report.markup import escaped, number_text

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.tasks import MetricSpec

__all__ = ['render_sweep_html']

_CSS = """
:root{--fg:#1d1d1f;--muted:#666;--line:#ddd;--bg:#fff;--soft:#f6f7f9}
*{box-sizing:border-box}
body{margin:0;font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;
color:var(--fg);background:var(--bg)}
main{max-width:1400px;margin:0 auto;padding:20px 24px 48px}
h1{font-size:22px;margin:0 0 4px}
h2{font-size:18px;margin:28px 0 10px;padding-bottom:4px;border-bottom:1px solid var(--line)}
.meta{color:var(--muted);margin:0 0 12px}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-weight:600;font-size:12px;
color:#fff;background:#777;white-space:nowrap}
.badge.complete{background:#2e7d32}.badge.failed{background:#c62828}
.badge.interrupted,.badge.running,.badge.pending{background:#e65100}
.badge.best{background:#1565c0}
.banner{border:1px solid #e0b000;background:#fff8e1;border-radius:6px;padding:10px 14px;
margin:12px 0}
.banner.bad{border-color:#c62828;background:#ffebee}
.banner ul{margin:4px 0 0;padding-left:20px}
table{border-collapse:collapse;width:100%;margin:6px 0 10px;font-variant-numeric:tabular-nums}
th,td{border:1px solid var(--line);padding:5px 8px;text-align:left;vertical-align:top}
th{background:var(--soft);font-weight:600}
td.cell.best{background:#e8f1fb}
td.cell.failed{background:#ffebee}
td.cell.flagged{outline:2px dashed #e0b000;outline-offset:-3px}
.n{white-space:nowrap}
.ci{color:var(--muted);font-size:12px}
.where{color:var(--muted);font-size:12px;overflow-wrap:anywhere}
.flags{color:#8a4b00;font-size:12px}
.error{color:#c62828;font-size:12px}
.table-wrap{overflow-x:auto}
code{font:12px/1.4 ui-monospace,SFMono-Regular,Menlo,Consolas,monospace}
footer{margin-top:36px;color:var(--muted);font-size:12px}
"""


def _ci(interval: Sequence[float] | None, digits: int = 2) -> str:
    if not interval:
        return ''
    return f' <span class="ci">[{interval[0]:.{digits}f}, {interval[1]:.{digits}f}]</span>'


def _column(entry: Mapping[str, Any]) -> str:
    params = ' '.join(f'{k}={v}' for k, v in entry['params'].items())
    return f'{entry["backend"]} {params}'.strip()


#: Backends that replay the outputs recorded in the bag: their FPS is how fast the bag was
#: read, no detector's speed, so they never get "best FPS" (and show no FPS).
_RECORDINGS = frozenset({'recorded'})


def _best(entries: Sequence[Mapping[str, Any]], metric: str, lower: bool = False) -> set[int]:
    """Indices of the cells with the best ``metric`` (the highest; the lowest with ``lower``)
    of at least two with a value; FPS among the replayed backends only."""
    scored = [
        (e['metrics'][metric], e['index'])
        for e in entries
        if e['status'] == 'complete'
        and e.get('metrics')
        and e['metrics'].get(metric) is not None
        and not (metric == 'fps' and e['backend'] in _RECORDINGS)
    ]
    if len(scored) < 2:
        return set()
    top = (min if lower else max)(value for value, _ in scored)
    return {index for value, index in scored if value == top}


class _Figure:
    """A main figure a cell shows: its spec, whether every cell shows it (one that every
    backend has: a value or '-') or only those with a value, and its "best" badge."""

    __slots__ = ('always', 'badge', 'spec')

    def __init__(self, spec: MetricSpec, always: bool) -> None:
        self.spec, self.always = spec, always
        # the label without its threshold: "best mAP" for mAP@0.5
        self.badge = f'best {spec.label.partition("@")[0]}'


def _figures() -> list[_Figure]:
    """The registered tasks' metrics a sweep shows that are their task's main figure, in
    sweep.csv's order; those of a task shown on every row (``TaskViews.terminal='always'``,
    the boxes) in every cell."""
    from replaybench.tasks import all_metrics, get_task, task_names, task_views

    every_row = {
        m.name
        for name in task_names()
        if task_views(task := get_task(name)).terminal == 'always'
        for m in task.metrics
    }
    shown = sorted(all_metrics(), key=lambda m: m.appended)
    return [_Figure(m, m.name in every_row) for m in shown if m.sweep and m.accuracy and m.main]


def _cell_html(
    entry: Mapping[str, Any], best_fps: bool, figures: Sequence[_Figure], best: set[str]
) -> str:
    status = entry['status']
    classes = ['cell']
    if status == 'failed':
        classes.append('failed')
    if best_fps:
        classes.append('best')
    if entry.get('flags'):
        classes.append('flagged')
    parts = [f'<span class="badge {escaped(status)}">{escaped(status)}</span>']
    if best_fps:
        parts.append(' <span class="badge best">best FPS</span>')
    parts += [
        f' <span class="badge best">{escaped(f.badge)}</span>'
        for f in figures
        if f.spec.name in best
    ]
    m = entry.get('metrics')
    if m:
        fps, p50, p99 = (
            number_text(m.get(key), spec, '-')
            for key, spec in (('fps', '.1f'), ('p50_ms', '.2f'), ('p99_ms', '.2f'))
        )
        accuracy = ''.join(
            f'{escaped(f.spec.label)} '
            f'{number_text(m.get(f.spec.name), f".{f.spec.terminal_digits}f", "-")} · '
            for f in figures
            if f.always or m.get(f.spec.name) is not None
        )
        fps = (
            '<div class="where">recorded outputs: no replay speed</div>'
            if entry['backend'] in _RECORDINGS
            else f'<div class="n">{fps} FPS{_ci(m.get("fps_ci"), 1)}</div>'
        )
        parts.append(
            fps + f'<div class="n">p50 {p50} ms{_ci(m.get("p50_ci"))}</div>'
            f'<div class="n">p99 {p99} ms{_ci(m.get("p99_ci"))}</div>'
            f'<div class="n">{accuracy}{m.get("frames")} frames</div>'
        )
    if entry.get('hostname') or entry.get('node_id'):
        node = entry.get('hostname') or str(entry.get('node_id'))[:12]
        gpu = f' · GPU {",".join(entry["gpu_ids"])}' if entry.get('gpu_ids') else ''
        concurrency = (entry.get('concurrency') or {}).get('max_cells_on_node')
        shared = f' · {concurrency} cell(s) at once' if concurrency else ''
        parts.append(f'<div class="where">{escaped(node)}{escaped(gpu)}{escaped(shared)}</div>')
    if entry.get('flags'):
        parts.append(f'<div class="flags">{escaped("; ".join(entry["flags"]))}</div>')
    if entry.get('error'):
        parts.append(f'<div class="error">{escaped(entry["error"])}</div>')
    if entry.get('run_dir') and entry.get('has_report'):
        parts.append(f'<div><a href="{escaped(entry["run_dir"])}/report.html">report</a></div>')
    elif entry.get('run_dir'):
        parts.append(f'<div><code>{escaped(entry["run_dir"])}</code></div>')
    return f'<td class="{" ".join(classes)}">{"".join(parts)}</td>'


def _matrix(record: Mapping[str, Any]) -> str:
    entries = record['cells']
    report = bool(record.get('settings', {}).get('report', True))
    columns = list(dict.fromkeys(_column(e) for e in entries))
    inputs = {e['input_index']: e['input'] for e in entries}
    head = ''.join(f'<th>{escaped(c)}</th>' for c in columns)
    figures = _figures()
    rows = []
    for number in sorted(inputs):
        mine = [e for e in entries if e['input_index'] == number]
        fps = _best(mine, 'fps')
        bests = {f.spec.name: _best(mine, f.spec.name, f.spec.better == 'lower') for f in figures}
        by_column = {_column(e): e for e in mine}
        cells = []
        for column in columns:
            entry = by_column.get(column)
            if entry is None:
                cells.append('<td></td>')
                continue
            shown = {**entry, 'has_report': report}
            best = {name for name, found in bests.items() if entry['index'] in found}
            cells.append(_cell_html(shown, entry['index'] in fps, figures, best))
        rows.append(f'<tr><th>{escaped(inputs[number])}</th>{"".join(cells)}</tr>')
    return (
        '<h2>Matrix</h2><div class="table-wrap"><table>'
        f'<tr><th>input \\ backend</th>{head}</tr>{"".join(rows)}</table></div>'
    )


def _amount(name: str, value: float) -> str:
    if name in ('memory', 'object_store_memory'):
        return f'{name}: {value / (1 << 30):.1f} GiB'
    return f'{name}: {value:g}'


def _resources(resources: Mapping[str, float]) -> str:
    return ', '.join(_amount(k, v) for k, v in resources.items())


def _engine(record: Mapping[str, Any]) -> str:
    engine = record.get('engine')
    if not engine:
        return '<h2>Ray</h2><p class="meta">No cell ran in this invocation.</p>'
    resources = _resources(engine['resources'])
    nodes = ''.join(
        f'<tr><td><code>{escaped(str(n["node_id"])[:12])}</code>'
        f'{" (head)" if n["node_id"] == engine.get("head_node_id") else ""}</td>'
        f'<td>{escaped(n.get("hostname"))}</td><td>{escaped(n.get("ip"))}</td>'
        f'<td>{"alive" if n.get("alive") else "dead"}</td>'
        f'<td>{escaped(_resources(n["resources"]))}</td></tr>'
        for n in engine['nodes']
    )
    placement = engine['placement']
    return (
        '<h2>Ray</h2>'
        f'<p class="meta">Ray {escaped(engine["ray_version"])} · {escaped(engine["mode"])} · '
        f'address <code>{escaped(engine.get("address"))}</code> · '
        f'CPU cells: {escaped(placement["cpu_cells"])} · '
        f'GPU cells: {escaped(placement["gpu_cells"])}</p>'
        f'<p class="meta">Cluster resources: {escaped(resources)}</p>'
        '<div class="table-wrap"><table><tr><th>node</th><th>host</th><th>ip</th><th>state</th>'
        f'<th>resources</th></tr>{nodes}</table></div>'
    )


def _banners(record: Mapping[str, Any]) -> str:
    entries = record['cells']
    failed = [e for e in entries if e['status'] == 'failed']
    flagged = [e for e in entries if e.get('flags')]
    out = []
    if failed:
        items = ''.join(
            f'<li><code>{escaped(e["cell"])}</code>: {escaped(e.get("error"))}</li>' for e in failed
        )
        out.append(
            f'<div class="banner bad"><strong>{len(failed)} cell(s) failed</strong>'
            f'<ul>{items}</ul></div>'
        )
    if flagged:
        items = ''.join(
            f'<li><code>{escaped(e["cell"])}</code>: {escaped("; ".join(e["flags"]))}</li>'
            for e in flagged
        )
        out.append(
            f'<div class="banner"><strong>{len(flagged)} cell(s) measured under different '
            f'conditions</strong><ul>{items}</ul></div>'
        )
    return ''.join(out)


def render_sweep_html(record: Mapping[str, Any]) -> str:
    """The sweep.html page of a sweep.json record."""
    counts = record['counts']
    status = record['status']
    summary = (
        f'{counts["cells"]} cells: {counts["complete"]} complete ({counts["resumed"]} kept from '
        f'an earlier run), {counts["failed"]} failed, {counts["interrupted"]} interrupted'
    )
    body = [
        (
            '<h1>replaybench sweep '
            f'<span class="badge {escaped(status)}">{escaped(status)}</span></h1>'
        ),
        (
            f'<p class="meta">{escaped(summary)} · started {escaped(record["started_at"])} · '
            f'{record["wall_s"]:.1f} s</p>'
        ),
        f'<p class="meta"><code>{escaped(" ".join(record["command"]))}</code></p>',
        _banners(record),
        _matrix(record),
        _engine(record),
        (
            f'<footer>replaybench {escaped(record["tool"]["version"])} · sweep.json schema '
            f'{record["schema_version"]} · sweep.csv has one row per cell</footer>'
        ),
    ]
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        '<title>replaybench sweep</title>'
        f'<style>{_CSS}</style></head><body><main>{"".join(body)}</main></body></html>\n'
    )
