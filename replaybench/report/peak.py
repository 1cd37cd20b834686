"""peak.html: the page of a peak.json (``replaybench peak``), rendered from it alone."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.errors import SourceError
from replaybench.report.cards import environment_html
from replaybench.report.formats import definition_list, fmt, fmt_frac, fmt_hz, fmt_ms, fmt_value
from replaybench.report.markup import escaped
from replaybench.report.page import page_html
from replaybench.report.svg import Rule, Series, line_chart
from replaybench.results.atomic import write_text_atomic
from replaybench.results.io import read_peak_result, to_json
from replaybench.results.numbers import finite_number

if TYPE_CHECKING:
    from replaybench.results.model import PeakResult

__all__ = ['load_peak', 'render_peak_html', 'render_peak_report']

_OK = '#2e7d32'
_FAIL = '#c62828'


def load_peak(out_dir: str | Path) -> PeakResult:
    """Read ``out_dir/peak.json``; SourceError with the reason when it is not a readable one."""
    path = Path(out_dir) / 'peak.json'
    if not path.exists():
        msg = f'{out_dir}: no peak.json (not a replaybench peak folder, or the sweep did not end)'
        raise SourceError(msg)
    return read_peak_result(path)


def _peak_verdict(peak: PeakResult) -> str:
    settings = peak.settings
    max_drop = finite_number(settings.max_drop)
    bound = finite_number(settings.p99_bound_ms)
    rule = f'at most {100 * (max_drop or 0):g} % of the frames dropped'
    if bound is not None:
        rule += f' and p99 latency at most {bound:g} ms'
    best = finite_number(peak.peak_hz)
    failing = finite_number(peak.first_failing_hz)
    if best is None:
        return (
            '<p><strong>No tested rate passed</strong>, down to '
            f'{escaped(fmt_hz(settings.min_hz))} ({escaped(rule)}).</p>'
        )
    text = (
        f'<p><strong>Peak sustainable rate: {escaped(fmt_hz(best))}</strong> per topic — the '
        f'highest tested rate with {escaped(rule)}.'
    )
    if failing is not None:
        text += f' The lowest failing rate tested was {escaped(fmt_hz(failing))}'
        resolution = failing - best
        text += f' (resolution {resolution:.3g} Hz).' if resolution > 0 else '.'
    if peak.limit_reached:
        text += ' Every rate up to the search limit passed: the backend may keep up with more.'
    return text + '</p>'


def _peak_trials(peak: PeakResult) -> str:
    best = finite_number(peak.peak_hz)
    body = []
    for number, trial in enumerate(peak.trial_rows, 1):
        ok = trial.ok
        rate = finite_number(trial.rate_hz)
        marker = ' class="peak"' if best is not None and rate == best else ''
        verdict = f'<span style="color:{_OK if ok else _FAIL}">{"pass" if ok else "fail"}</span>'
        body.append(
            f'<tr{marker}><td class="n">{number}</td>'
            f'<td class="n">{escaped(fmt_hz(rate))}</td>'
            f'<td class="n">{escaped(fmt_value(trial.frames))}</td>'
            f'<td class="n">{escaped(fmt_value(trial.dropped))}</td>'
            f'<td class="n">{escaped(fmt_frac(trial.drop_fraction))}</td>'
            f'<td class="n">{escaped(fmt_ms(trial.p99_ms))}</td>'
            f'<td>{verdict}</td><td><code>{escaped(trial.run_dir)}</code></td></tr>',
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
    trials = sorted(
        (t for t in peak.trial_rows if finite_number(t.rate_hz)), key=lambda t: t.rate_hz
    )
    if not trials:
        return ''
    settings = peak.settings
    best = finite_number(peak.peak_hz)
    rules_x = [Rule('x', best, f'peak {best:g} Hz', _OK)] if best is not None else []
    charts = []
    for key, title, y_label, limit, scale in (
        ('drop_fraction', 'Dropped frames vs rate', 'dropped (%)', settings.max_drop, 100.0),
        ('p99_ms', 'p99 latency vs rate', 'p99 latency (ms)', settings.p99_bound_ms, 1.0),
    ):
        points: list[tuple[float, float, bool]] = []
        for t in trials:
            x, y = finite_number(t.rate_hz), finite_number(getattr(t, key))
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
        if limit is not None and finite_number(limit) is not None:
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
        f'<span class="badge {escaped(status)}">{escaped(status)}</span>',
        f'backend {escaped(peak.backend or "?")}',
        f'started {escaped(peak.started_at or "?")}',
    ]
    wall = finite_number(peak.wall_s)
    if wall is not None:
        meta.append(f'wall time {wall:.1f} s')
    meta.append(f'{escaped(tool.name)} {escaped(tool.version or "?")}')
    items: list[tuple[str, Any]] = [
        ('input', source.path or None),
        ('sha256', source.sha256),
        ('start rate', f'{fmt_hz(start.hz)} (from the {start.source or "?"})'),
        ('max-rate probe', f'{fmt(start.probe_fps)} frames/s per topic'),
        ('recorded rate', fmt_hz(start.recorded_hz)),
    ]
    items += list(to_json(peak.settings).items())
    banner = ''
    if status == 'interrupted':
        banner = (
            '<div class="banner" role="alert"><strong>Warnings</strong><ul><li>The sweep was '
            'interrupted: the result covers only the trials that finished.</li></ul></div>'
        )
    footer = (
        f'<footer>Generated by {escaped(tool.name)} '
        f'{escaped(tool.version)} from peak.json (schema '
        f'{escaped(peak.schema_version)}). Self-contained: no external resources.'
        '</footer>'
    )
    body = [
        f'<header><h1>replaybench peak rate</h1><p class="meta">{" · ".join(meta)}</p></header>',
        banner,
        _peak_verdict(peak),
        '<div class="cards">',
        f'<div class="card"><h3>Sweep</h3>{definition_list(items)}</div>',
        environment_html(peak.environment),
        '</div>',
        '<h2 id="trials">Trials</h2>',
        _peak_trials(peak),
        _peak_charts(peak),
        f'<h3>Command</h3><pre>{escaped(shlex.join(peak.command))}</pre>' if peak.command else '',
        footer,
    ]
    title = f'replaybench peak rate · {escaped(peak.backend or "?")}'
    return page_html(title, ''.join(body))


def render_peak_report(out_dir: str | Path) -> Path:
    """Write ``out_dir/peak.html`` (atomically) from ``out_dir/peak.json`` and return its path."""
    peak = load_peak(out_dir)
    out = Path(out_dir) / 'peak.html'
    write_text_atomic(out, render_peak_html(peak))
    return out
