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


def _rule(peak: PeakResult) -> str:
    settings = peak.settings
    max_drop = finite_number(settings.max_drop)
    bound = finite_number(settings.p99_bound_ms)
    rule = f'at most {100 * (max_drop or 0):g} % of the frames dropped'
    if bound is not None:
        rule += f' and p99 latency at most {bound:g} ms'
    return rule


def _cameras_verdict(peak: PeakResult) -> str:
    """``peak --cameras``: the copies sustained, beside the copies predicted."""
    rig = peak.cameras
    assert rig is not None
    count = len(rig.cameras)
    what = f'{count} camera{"s" if count != 1 else ""} at {fmt_hz(rig.recorded_hz)}'
    text = (
        f'<p><strong>Sustains {escaped(rig.copies or 0)} × this rig</strong> '
        f'({escaped(what)}) — the most copies of the camera set, each camera of each copy in a '
        f'pipeline of its own, replayed at the recorded rate with {escaped(_rule(peak))}.'
    )
    if rig.first_failing_copies is not None:
        text += f' The fewest copies that failed a trial: {escaped(rig.first_failing_copies)}.'
    if peak.limit_reached:
        text += ' Every count up to the search limit passed: the backend may sustain more.'
    service = finite_number(rig.service_ms)
    if rig.predicted_copies is not None and service is not None:
        text += (
            f"</p><p>Predicted at most {escaped(rig.predicted_copies)} × from one camera's "
            f'service time {service:.2f} ms on {escaped(rig.cores)} core(s): '
            f'floor({escaped(rig.cores)} / ({count} × {fmt_hz(rig.recorded_hz)} × '
            f'{service:.2f} ms)), an upper bound: copies sharing a core pay for their '
            'contention.'
        )
    return text + '</p>'


def _peak_verdict(peak: PeakResult) -> str:
    if peak.cameras is not None:
        return _cameras_verdict(peak)
    settings = peak.settings
    rule = _rule(peak)
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
        if peak.cameras is not None:
            best_copies = peak.cameras.copies
            marker = ' class="peak"' if trial.copies == best_copies is not None else ''
        verdict = f'<span style="color:{_OK if ok else _FAIL}">{"pass" if ok else "fail"}</span>'
        copies = f'<td class="n">{escaped(fmt_value(trial.copies))}</td>' if peak.cameras else ''
        body.append(
            f'<tr{marker}><td class="n">{number}</td>{copies}'
            f'<td class="n">{escaped(fmt_hz(rate))}</td>'
            f'<td class="n">{escaped(fmt_value(trial.frames))}</td>'
            f'<td class="n">{escaped(fmt_value(trial.dropped))}</td>'
            f'<td class="n">{escaped(fmt_frac(trial.drop_fraction))}</td>'
            f'<td class="n">{escaped(fmt_ms(trial.p99_ms))}</td>'
            f'<td>{verdict}</td><td><code>{escaped(trial.run_dir)}</code></td></tr>',
        )
    return (
        '<div class="table-wrap"><table><thead><tr><th class="n">#</th>'
        + ('<th class="n">copies</th>' if peak.cameras else '')
        + '<th class="n">rate</th>'
        '<th class="n">frames</th><th class="n">dropped</th><th class="n">dropped %</th>'
        '<th class="n">p99 ms</th><th>verdict</th><th>run folder</th></tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>'
        '<p class="muted">Trials in the order they ran. Frames and drops count from the end of '
        'the warm-up on; p99 is over the measured frames.</p>'
    )


def _peak_charts(peak: PeakResult) -> str:
    # a rate search plots against the rate, a --cameras one against the copies
    axis = 'rate_hz' if peak.cameras is None else 'copies'
    trials = sorted(
        (t for t in peak.trial_rows if finite_number(getattr(t, axis))),
        key=lambda t: float(getattr(t, axis)),
    )
    if not trials:
        return ''
    settings = peak.settings
    if peak.cameras is None:
        best = finite_number(peak.peak_hz)
        rules_x = [Rule('x', best, f'peak {best:g} Hz', _OK)] if best is not None else []
        x_label, versus = 'input rate per topic (Hz)', 'rate'
    else:
        best = finite_number(peak.cameras.copies)
        rules_x = [Rule('x', best, f'sustains {best:g} x', _OK)] if best is not None else []
        x_label, versus = 'copies of the camera set', 'copies'
    charts = []
    for key, title, y_label, limit, scale in (
        ('drop_fraction', f'Dropped frames vs {versus}', 'dropped (%)', settings.max_drop, 100.0),
        ('p99_ms', f'p99 latency vs {versus}', 'p99 latency (ms)', settings.p99_bound_ms, 1.0),
    ):
        points: list[tuple[float, float, bool]] = []
        for t in trials:
            x, y = finite_number(getattr(t, axis)), finite_number(getattr(t, key))
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
                x_label=x_label,
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
    if peak.cameras is not None:
        rig = peak.cameras
        items = [
            *items[:2],
            ('camera set', ', '.join(rig.cameras)),
            ('recorded rate', fmt_hz(rig.recorded_hz)),
            ("one camera's service time", f'{fmt_ms(rig.service_ms)} ms ({rig.service_run_dir})'),
            ('cores', rig.cores),
            ('predicted copies', rig.predicted_copies),
            ('most copies tried', rig.max_copies),
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
