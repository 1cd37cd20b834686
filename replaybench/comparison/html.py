"""comparison.html: one self-contained page (inline CSS and SVG, no scripts) for a comparison."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

from replaybench.comparison.core import (
    ACCURACY_METRICS,
    METRICS,
    RECORDED_METRICS,
    TAG_METRICS,
    TIMING_METRICS,
)
from replaybench.comparison.gate import gate_verdict, method_text
from replaybench.comparison.paired_html import paired_html
from replaybench.comparison.runs import CV_LIMIT, engine_text, inputs_match
from replaybench.report.markup import escaped, number_text
from replaybench.report.svg import Label, colour, fit_label, nice_ticks, step_cdf
from replaybench.results.blocks import BLOCK_FRAMES, MAX_BLOCKS, MIN_BLOCKS
from replaybench.results.bootstrap import MIN_FRAMES
from replaybench.tasks import all_metrics

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.comparison.core import Comparison, MetricComparison, Row
    from replaybench.comparison.gate import GateResult

__all__ = ['render_comparison_html']

_CSS = """
:root{--fg:#1d1d1f;--muted:#666;--line:#ddd;--bg:#fff;--soft:#f6f7f9}
*{box-sizing:border-box}
body{margin:0;font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;
color:var(--fg);background:var(--bg)}
main{max-width:1280px;margin:0 auto;padding:20px 24px 48px}
h1{font-size:22px;margin:0 0 4px}
h2{font-size:18px;margin:28px 0 10px;padding-bottom:4px;border-bottom:1px solid var(--line)}
h3{font-size:15px;margin:18px 0 8px}
.meta{color:var(--muted);margin:0 0 12px}
.thumbs{display:flex;flex-wrap:wrap;gap:10px}.thumbs figure{margin:0;max-width:100%}
.thumbs img{display:block;max-width:100%;height:auto;border:1px solid var(--line)}
.thumbs figcaption{color:var(--muted);font-size:12px}
.badge{display:inline-block;padding:1px 8px;border-radius:10px;font-weight:600;font-size:12px;
color:#fff;background:#777;white-space:nowrap}
.badge.pass,.badge.match{background:#2e7d32}.badge.fail,.badge.mismatch{background:#c62828}
.badge.ns{background:#9e9e9e}.badge.sig{background:#1565c0}.badge.unknown{background:#e65100}
.badge.inconclusive{background:#e65100}
.banner{border:1px solid #e0b000;background:#fff8e1;border-radius:6px;padding:10px 14px;
margin:12px 0}
.banner.bad{border-color:#c62828;background:#ffebee}
.banner strong{display:block;margin-bottom:4px}
.banner ul{margin:4px 0 0;padding-left:20px}
table{border-collapse:collapse;width:100%;margin:6px 0 10px;font-variant-numeric:tabular-nums}
th,td{border-bottom:1px solid var(--line);padding:4px 8px;text-align:left;vertical-align:top}
th{background:var(--soft);font-weight:600;white-space:nowrap}
td.n,th.n{text-align:right;white-space:nowrap}
td.flags{color:#8a4b00;font-size:12px}
tr.flagrow td{border-top:none;padding-top:0}
table.summary tr:has(+ tr.flagrow) td{border-bottom:none}
td.run{min-width:120px;max-width:200px;overflow-wrap:anywhere}
td.n .ci{white-space:normal}
td.flags{white-space:normal;overflow-wrap:anywhere}
tr.base td{background:#fafafa}
.ci{color:var(--muted);font-size:12px;display:block}
.swatch{display:inline-block;width:10px;height:10px;border-radius:2px;margin-right:6px}
.table-wrap{overflow-x:auto}
.charts{display:flex;flex-wrap:wrap;gap:10px}
svg.chart{max-width:100%;height:auto;background:#fff;border:1px solid var(--line);
border-radius:6px}
code{font:12px/1.4 ui-monospace,SFMono-Regular,Menlo,Consolas,monospace}
.muted{color:var(--muted)}
footer{margin-top:36px;color:var(--muted);font-size:12px}
"""

#: The compared metrics' table headings (``MetricSpec.short_label``).
_NAMES: dict[str, str] = {m.name: m.short_label for m in all_metrics() if m.name in METRICS}

_FONT = 'system-ui, -apple-system, Segoe UI, Roboto, sans-serif'


def _swatch(fill: str) -> str:
    return f'<span class="swatch" style="background:{escaped(fill)}"></span>'


def _pct(ratio: float) -> str:
    return f'{(ratio - 1.0) * 100.0:+.1f}%'


# --------------------------------------------------------------------------- sections


def _header(comparison: Comparison) -> str:
    base = comparison.baseline_run
    backend = (
        f' · baseline backend <code>{escaped(comparison.baseline_backend)}</code>'
        if comparison.baseline_backend
        else ''
    )
    level = round(comparison.confidence * 100)
    return (
        '<header><h1>replaybench comparison</h1>'
        f'<p class="meta">{len(comparison.runs)} run(s) · baseline <strong>{escaped(base.label)}'
        f'</strong>{backend} · {level}% CIs from {comparison.n_boot} circular block-bootstrap '
        f'resamples (seed {comparison.seed})</p></header>'
    )


def _inputs_status(comparison: Comparison) -> str:
    match = comparison.inputs_match
    if match is True:
        return (
            '<p><span class="badge match">inputs match</span> every run replayed the same '
            'files (sha256).</p>'
        )
    if match is False:
        return (
            '<div class="banner bad" role="alert"><strong>Inputs differ</strong>'
            '<span class="badge mismatch">sha256 mismatch</span> at least one run replayed other '
            'files than the baseline; the numbers are compared anyway, but not over the same '
            'data.</div>'
        )
    if len(comparison.runs) == 1:
        return (
            '<p><span class="badge match">one run</span> backends compared on the same frames.</p>'
        )
    return (
        '<p><span class="badge unknown">inputs not checked</span> a run folder does not record '
        'the sha256 of its inputs.</p>'
    )


def _banner(comparison: Comparison) -> str:
    if not comparison.warnings:
        return ''
    body = ''.join(f'<li>{escaped(w)}</li>' for w in comparison.warnings)
    return f'<div class="banner" role="alert"><strong>Warnings</strong><ul>{body}</ul></div>'


_BADGES = {
    'failed': ('fail', 'FAIL', 'fail'),
    'passed': ('pass', 'PASS', 'pass'),
    'inconclusive': ('inconclusive', 'INCONCLUSIVE', 'inconclusive'),
}


def _gate(gate: Sequence[GateResult], conditions: Sequence[str], strict: bool, allow: bool) -> str:
    if not conditions:
        return ''
    css, word, _ = _BADGES[gate_verdict(gate)]
    badge = f'<span class="badge {css}">{word}</span>'
    if css == 'inconclusive' and allow:
        badge += ' <span class="muted">(allowed: exit 0)</span>'
    mode = (
        'strict: the point estimate is judged'
        if strict
        else 'a condition fails when its whole CI lies past the threshold, passes when none of '
        'it does, and is inconclusive when the CI straddles the threshold or there is none'
    )
    listed = ', '.join(f'<code>{escaped(c)}</code>' for c in conditions)
    rows = []
    for r in gate:
        css, _, word = _BADGES[r.verdict]
        verdict = f'<span class="badge {css}">{word}</span>'
        if r.method:
            verdict += f'<span class="ci">{escaped(r.method)}</span>'
        unit = '%' if r.condition.rstrip().endswith('%') else ''
        ci = (
            f'{number_text(r.ci_low, ".4g")}{unit} … {number_text(r.ci_high, ".4g")}{unit}'
            if r.ci_low is not None and r.ci_high is not None
            else 'no CI'
        )
        change = f'{number_text(r.estimate, ".4g")}{unit}' if r.estimate is not None else '–'
        rows.append(
            f'<tr><td>{verdict}</td><td><code>{escaped(r.condition)}</code></td><td>{escaped(r.run)}</td>'
            f'<td>{escaped(r.backend)}</td><td><code>{escaped(r.topic)}</code></td>'
            f'<td class="n">{escaped(change)}</td><td class="n">{escaped(ci)}</td>'
            f'<td>{escaped(r.explanation)}</td></tr>',
        )
    table = (
        '<div class="table-wrap"><table><thead><tr><th></th><th>condition</th><th>run</th>'
        '<th>backend</th><th>topic</th><th class="n">change</th><th class="n">CI</th>'
        f'<th>explanation</th></tr></thead><tbody>{"".join(rows)}</tbody></table></div>'
    )
    if not gate:
        table = '<p class="muted">No candidate row to judge.</p>'
    return (
        f'<h2 id="gate">Gate {badge}</h2><p class="meta">Conditions {listed}; {escaped(mode)}. '
        'Change: percent for relative conditions, the metric unit for absolute ones.</p>' + table
    )


def _runs(comparison: Comparison) -> str:
    base = comparison.baseline_run
    rows = []
    for run in comparison.runs:
        shas = ', '.join(s[:12] if s else '?' for s in run.input_sha256) or '–'
        if run.index == base.index:
            status = '<span class="badge">baseline</span>'
        else:
            status = {
                True: '<span class="badge match">match</span>',
                False: '<span class="badge mismatch">differ</span>',
                None: '<span class="badge unknown">unknown</span>',
            }[inputs_match(run, base)]
        engines = '; '.join(
            f'{label}: {engine_text(info)}'
            for label, info in run.backend_info.items()
            if engine_text(info)
        )
        load = (
            f'{run.load_average:g} / {run.cores} cores'
            if run.load_average is not None and run.cores
            else number_text(run.load_average, '.4g')
        )
        rows.append(
            f'<tr><td>{_swatch(colour(run.index))}{escaped(run.label)}'
            f'<span class="ci">{escaped(run.dir)}</span></td><td>{escaped(run.status)}</td>'
            f'<td>{escaped(run.cpu_model or "–")}</td>'
            f'<td>{escaped(", ".join(run.gpus) or "none")}</td>'
            f'<td>{escaped(run.governor or "unknown")}</td><td class="n">{escaped(load)}</td>'
            f'<td>{escaped(engines or "–")}</td>'
            f'<td><code title="{escaped(", ".join(s or "?" for s in run.input_sha256))}">'
            f'{escaped(shas)}</code> {status}</td></tr>',
        )
    return (
        '<h2 id="runs">Runs</h2><div class="table-wrap"><table><thead><tr><th>run</th>'
        '<th>status</th><th>CPU</th><th>GPUs</th><th>governor</th><th class="n">load</th>'
        '<th>engines</th><th>inputs (sha256)</th></tr></thead>'
        f'<tbody>{"".join(rows)}</tbody></table></div>'
    )


def _timing_cell(m: MetricComparison, role: str) -> str:
    value = f'{escaped(number_text(m.value, ".4g"))}'
    if role != 'candidate':
        ci = (
            f'<span class="ci">[{escaped(number_text(m.value_ci[0], ".4g"))}, '
            f'{escaped(number_text(m.value_ci[1], ".4g"))}]</span>'
            if m.value_ci
            else ''
        )
        return f'<td class="n">{value}{ci}</td>'
    if m.ratio is None:
        return f'<td class="n">{value}<span class="ci">no ratio</span></td>'
    ratio = f'×{m.ratio:.3f} ({_pct(m.ratio)})'
    how = method_text(m)
    typical = (
        f'<span class="ci">typical ×{m.typical_ratio:.3f} ({escaped(how)})</span>'
        if m.typical_ratio is not None
        else ''
    )
    if m.ratio_ci is None:
        detail = f'{typical}<span class="ci">no CI</span>'
    else:
        lo, hi = m.ratio_ci
        badge = (
            '<span class="badge sig">significant</span>'
            if m.significant
            else '<span class="badge ns">not significant</span>'
        )
        detail = f'{typical}<span class="ci">CI ×{lo:.3f} … ×{hi:.3f}</span>{badge}'
    return f'<td class="n">{value}<span class="ci">{escaped(ratio)}</span>{detail}</td>'


def _recorded_cell(m: MetricComparison, role: str) -> str:
    """A recorded latency: as a timing metric where the row has it; for a replayed candidate
    against a recording, the recording's value (the row's own latency is in its median)."""
    if role == 'candidate' and m.value is None and m.baseline is not None:
        baseline = escaped(number_text(m.baseline, '.4g'))
        return (
            f'<td class="n">–<span class="ci">baseline recording {baseline}</span>'
            '<span class="ci">this row replays</span></td>'
        )
    return _timing_cell(m, role)


def _accuracy_cell(m: MetricComparison, role: str) -> str:
    value = escaped(number_text(m.value, '.4g'))
    if role != 'candidate' or m.diff is None:
        return f'<td class="n">{value}</td>'
    if m.diff_ci is None:
        return f'<td class="n">{value}<span class="ci">Δ {m.diff:+.4f} (no CI)</span></td>'
    lo, hi = m.diff_ci
    interval = f'Δ {m.diff:+.4f} [{lo:+.4f}, {hi:+.4f}] paired'
    return f'<td class="n">{value}<span class="ci">{escaped(interval)}</span></td>'


#: The main accuracy figure of each task, read first (``MetricSpec.main``), in registry order.
_MAIN_ACCURACY: tuple[str, ...] = tuple(
    m.name for m in all_metrics() if m.main and m.accuracy and m.name in METRICS
)
#: The timing figures read first (the mean is under More figures).
_MAIN_TIMING: tuple[str, ...] = ('median_ms', 'p99_ms', 'fps')
#: A recording's main latency, read first where a row has one.
_MAIN_RECORDED: tuple[str, ...] = ('recorded_pipeline_ms',)


def _cells(row: Row, metrics: Sequence[str]) -> list[str]:
    role = row.role
    out = []
    for m in metrics:
        if m in TIMING_METRICS:
            out.append(_timing_cell(row.metrics[m], role))
        elif m in RECORDED_METRICS:
            out.append(_recorded_cell(row.metrics[m], role))
        else:
            out.append(_accuracy_cell(row.metrics[m], role))
    return out


def _summary(comparison: Comparison) -> str:
    """The figures read first (n, median, p99, FPS, the task's main accuracy, a recording's
    pipeline latency), narrow enough for a laptop's screen; the others under More figures."""
    accuracy = [
        m
        for m in (*ACCURACY_METRICS, *TAG_METRICS)
        if any(r.metrics[m].value is not None for r in comparison.rows)
    ]
    recorded = [
        m
        for m in RECORDED_METRICS
        if any(r.metrics[m].value is not None or r.metrics[m].baseline is not None
               for r in comparison.rows)
    ]  # fmt: skip
    main = [
        *_MAIN_TIMING,
        *(m for m in _MAIN_ACCURACY if m in accuracy),
        *(m for m in _MAIN_RECORDED if m in recorded),
    ]
    more = [m for m in (*TIMING_METRICS, *accuracy, *recorded) if m not in main]
    where = ['run', 'backend', 'topic', 'role']
    head = [*where, 'n', *(_NAMES[m] for m in main)]
    th = ''.join(
        f'<th class="n">{escaped(h)}</th>' if i >= 4 else f'<th>{escaped(h)}</th>'
        for i, h in enumerate(head)
    )
    more_th = ''.join(f'<th>{escaped(h)}</th>' for h in where) + ''.join(
        f'<th class="n">{escaped(_NAMES[m])}</th>' for m in more
    )
    body, more_body = [], []
    for row in comparison.rows:
        role = row.role
        versus = (
            f'<span class="ci">vs {escaped(row.baseline_backend)}</span>'
            if role == 'candidate' and row.baseline_backend != row.backend
            else ''
        )
        first = [
            f'<td class="run">{_swatch(colour(row.run))}{_label_html(comparison, row)}</td>',
            f'<td>{escaped(row.backend)}{versus}</td>',
            f'<td><code>{escaped(row.topic).replace("/", "/<wbr>")}</code></td>',
            f'<td>{escaped(role)}</td>',
        ]
        cells = [*first, f'<td class="n">{row.measured}</td>', *_cells(row, main)]
        css = 'base' if role == 'baseline' else ''
        body.append(f'<tr class="{css}">{"".join(cells)}</tr>')
        if row.flags:
            flags = '; '.join(escaped(f) for f in row.flags)
            body.append(
                f'<tr class="{css} flagrow"><td></td><td class="flags" colspan="{len(head) - 1}">'
                f'⚑ {flags}</td></tr>'
            )
        more_body.append(f'<tr class="{css}">{"".join([*first, *_cells(row, more)])}</tr>')
    names = ', '.join(_NAMES[m] for m in more)
    details = (
        f'<details id="summary-more"><summary>More figures: {escaped(names)}'
        '</summary><div class="table-wrap"><table class="summary-more"><thead><tr>'
        f'{more_th}</tr></thead><tbody>{"".join(more_body)}</tbody></table></div></details>'
        if more
        else ''
    )
    return (
        '<h2 id="summary">Summary</h2><div class="table-wrap"><table class="summary"><thead><tr>'
        f'{th}</tr></thead><tbody>{"".join(body)}</tbody></table></div>{details}'
        '<p class="muted">Candidate rows: value, ratio to the baseline row (candidate / '
        'baseline, whole runs), the typical ratio between blocks of frames (frames below '
        f'{MIN_FRAMES}) and its {round(comparison.confidence * 100)}% CI, which the gate '
        'judges; "not significant" when the CI contains 1. Baseline rows: value and the CI of '
        'the value itself. Accuracy: difference of the run.json numbers, without CI. Recorded: the '
        "latency a recording's outputs had on the robot (pipeline: output log time − image log "
        'time; capture: − image stamp), compared as the timings are, between blocks of '
        'consecutive outputs in log-time order; a replayed row against a recording shows the '
        "recording's value beside its own median. ⚑ flags: "
        "facts that make a row's timings doubtful or not comparable.</p>"
    )


# --------------------------------------------------------------------------- charts


class _Bar(NamedTuple):
    label: Label
    fill: str
    opacity: float
    value: float | None
    ci: tuple[float, float] | None


def _n(value: float) -> str:
    text = f'{value:.1f}'
    return '0.0' if text == '-0.0' else text


def _interval_chart(bars: Sequence[_Bar], *, title: str, x_label: str, width: int = 720) -> str:
    """Horizontal bars with confidence-interval whiskers."""
    longest = max((len(str(b.label)) for b in bars), default=4)
    label_w = min(300, max(60, int(longest * 6.6) + 12))
    left, right, top = label_w + 8, 80, 32
    bar_h, gap = 16, 6
    plot_h = max(1, len(bars)) * (bar_h + gap) + gap
    height = top + plot_h + 40
    plot_w = width - left - right
    highs = [b.ci[1] if b.ci else b.value for b in bars]
    hi = max((h for h in highs if h is not None and math.isfinite(h)), default=1.0) or 1.0
    ticks = nice_ticks(0.0, hi)
    span = ticks[-1] - ticks[0] or 1.0

    def sx(v: float) -> float:
        return left + (min(max(v, ticks[0]), ticks[-1]) - ticks[0]) / span * plot_w

    parts = [
        (
            f'<svg class="chart" viewBox="0 0 {width} {height}" width="{width}" '
            f'height="{height}" role="img" aria-label="{escaped(title)}" font-family="{_FONT}" '
            f'font-size="12"><title>{escaped(title)}</title>'
            '<text x="8" y="18" font-size="14" font-weight="600" fill="#222">'
            f'{escaped(title)}</text>'
        ),
    ]
    base = top + plot_h
    for tick in ticks:
        px = sx(tick)
        parts.append(
            f'<line x1="{_n(px)}" y1="{top}" x2="{_n(px)}" y2="{_n(base)}" stroke="#e4e4e4"/>'
            f'<text x="{_n(px)}" y="{_n(base + 16)}" text-anchor="middle" fill="#222">'
            f'{escaped(f"{tick:g}")}</text>',
        )
    for i, bar in enumerate(bars):
        y = top + gap + i * (bar_h + gap)
        mid = y + bar_h / 2
        shown = fit_label(bar.label, int(label_w / 6.6))
        parts.append(
            f'<text x="{left - 6}" y="{_n(mid + 4)}" text-anchor="end" fill="#222">'
            f'<title>{escaped(bar.label)}</title>{escaped(shown)}</text>',
        )
        if bar.value is None:
            parts.append(f'<text x="{left + 4}" y="{_n(mid + 4)}" fill="#666">n/a</text>')
            continue
        x1 = sx(bar.value)
        ci_text = f' [{bar.ci[0]:.4g}, {bar.ci[1]:.4g}]' if bar.ci else ''
        parts.append(
            f'<rect x="{left}" y="{_n(y)}" width="{_n(max(x1 - left, 0.5))}" height="{bar_h}" '
            f'fill="{escaped(bar.fill)}" fill-opacity="{bar.opacity:g}">'
            f'<title>{escaped(bar.label)}: {bar.value:.4g}{escaped(ci_text)}</title></rect>',
        )
        end = x1
        if bar.ci is not None:
            a, b = sx(bar.ci[0]), sx(bar.ci[1])
            end = max(end, b)
            parts.append(
                f'<path d="M{_n(a)} {_n(mid)}H{_n(b)}M{_n(a)} {_n(y + 3)}V{_n(y + bar_h - 3)}'
                f'M{_n(b)} {_n(y + 3)}V{_n(y + bar_h - 3)}" stroke="#222" stroke-width="1.4" '
                'fill="none"/>',
            )
        parts.append(
            f'<text x="{_n(end + 5)}" y="{_n(mid + 4)}" fill="#222">'
            f'{escaped(f"{bar.value:.4g}")}</text>',
        )
    parts.append(
        f'<path d="M{left} {top}V{_n(base)}H{left + plot_w}" fill="none" stroke="#444"/>'
        f'<text x="{_n(left + plot_w / 2)}" y="{_n(base + 32)}" text-anchor="middle" '
        f'fill="#222">{escaped(x_label)}</text></svg>',
    )
    return ''.join(parts)


def _run_label(comparison: Comparison, row: Row, tail: str = '') -> Label:
    """``row``'s run label then ``tail``, as a chart ``Label``: its machine is the middle."""
    head, machine, rest = comparison.runs[row.run].label_parts
    if not (head or machine or rest):
        head = row.run_label
    return Label(head, machine, rest + tail)


#: The most characters of a run label in the summary table (the Runs table has it whole).
_CELL_LABEL = 44


def _label_html(comparison: Comparison, row: Row) -> str:
    """The run label of a summary row: its machine shortened first, the whole as its tooltip."""
    shown = fit_label(_run_label(comparison, row), _CELL_LABEL)
    if shown == row.run_label:
        return escaped(shown)
    return f'<span title="{escaped(row.run_label)}">{escaped(shown)}</span>'


def _groups(comparison: Comparison) -> dict[tuple[str, str], list[Row]]:
    groups: dict[tuple[str, str], list[Row]] = {}
    for row in comparison.rows:
        key = (row.baseline_backend or row.backend, row.topic)
        groups.setdefault(key, []).append(row)
    return groups


def _charts(comparison: Comparison) -> str:
    level = round(comparison.confidence * 100)
    parts = ['<h2 id="latency">Latency per backend and topic</h2>']
    for (backend, topic), rows in _groups(comparison).items():

        def name(row: Row, kind: str = '', backend: str = backend) -> Label:
            """The row's run label, its machine the part shortened first in a chart."""
            tail = kind if row.backend == backend else f' · {row.backend}{kind}'
            return _run_label(comparison, row, tail=tail)

        def values(row: Row) -> list[float]:
            # a recording's row: its recorded pipeline latency (its replay is not timed)
            key = (row.run, row.backend, row.topic)
            found = comparison.recorded_latencies.get(key)
            if found is not None and not comparison.latencies[key].size:
                return [float(v) for v in found]
            return [float(v) for v in comparison.latencies[key]]

        def recorded(row: Row) -> bool:
            key = (row.run, row.backend, row.topic)
            return key in comparison.recorded_latencies and not comparison.latencies[key].size

        def label(row: Row, tag: str = '') -> Label:
            found = name(row, ' · recorded pipeline' if recorded(row) else '')
            return found._replace(head=tag + found.head)

        series = [(label(r), colour(r.run), values(r)) for r in rows]
        cdf = step_cdf(series, title=f'Latency CDF · {backend} · {topic}', x_label='latency (ms)')
        bars: list[_Bar] = []
        for r in rows:
            pairs = (('median_ms', 'p50', 0.55), ('p99_ms', 'p99', 1.0))
            if recorded(r):
                pairs = (
                    ('recorded_pipeline_ms', 'p50', 0.55),
                    ('recorded_pipeline_p99_ms', 'p99', 1.0),
                )
            for metric, tag, opacity in pairs:
                m = r.metrics[metric]
                bars.append(
                    _Bar(label(r, f'{tag} · '), colour(r.run), opacity, m.value, m.value_ci)
                )
        whiskers = _interval_chart(
            bars,
            title=f'p50 / p99 latency, {level}% CI · {backend} · {topic}',
            x_label='latency (ms)',
        )
        parts.append(f'<h3>{escaped(backend)} · <code>{escaped(topic)}</code></h3>')
        parts.append(f'<div class="charts">{cdf}{whiskers}</div>')
    return ''.join(parts)


def _footer(comparison: Comparison) -> str:
    level = round(comparison.confidence * 100)
    return (
        '<footer>Statistics: measured frames only (processed, after warm-up), in replay order. '
        f'Ratio CIs: {level}% exact Mann–Whitney (Moses) intervals of the Hodges–Lehmann ratio '
        f'between blocks of consecutive frames (clamp(n / {BLOCK_FRAMES}, {MIN_BLOCKS}, '
        f'{MAX_BLOCKS}) blocks per series, each summarised by the metric), between frames below '
        f'{MIN_FRAMES} frames. '
        f'Value CIs: {level}% percentile intervals from {comparison.n_boot} circular '
        'block-bootstrap resamples per series (block length max(ceil(n^(1/3)), Politis–White '
        f'estimate) frames, seed {comparison.seed}); none below {MIN_FRAMES} frames. '
        f'Unstable: latency coefficient of variation above {CV_LIMIT:g}. '
        'Self-contained: no external resources.</footer>'
    )


def render_comparison_html(
    comparison: Comparison,
    *,
    gate: Sequence[GateResult] = (),
    conditions: Sequence[str] = (),
    strict: bool = False,
    allow_inconclusive: bool = False,
) -> str:
    """The comparison page; every text taken from run folders is HTML-escaped."""
    verdict = ''
    if conditions:
        verdict = ' · ' + _BADGES[gate_verdict(gate)][1]
    body = [
        _header(comparison),
        _inputs_status(comparison),
        _banner(comparison),
        _gate(gate, conditions, strict, allow_inconclusive),
        _summary(comparison),
        paired_html(comparison),
        _charts(comparison),
        _runs(comparison),
        _footer(comparison),
    ]
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<title>replaybench comparison{escaped(verdict)}</title>'
        f'<style>{_CSS}</style></head><body><main>{"".join(body)}</main></body></html>\n'
    )
