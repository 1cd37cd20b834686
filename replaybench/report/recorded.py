"""Recorded latency beside replayed latency: the report's section and the terminal's lines.

A backend replaying outputs recorded in the bag (``recorded``) has no replay latency; its
summary row carries the recorded latency instead (``replaybench.results.recorded_latency``):
pipeline (output log time - image log time) and capture-to-output (output log time - image
header stamp). This module shows them beside the replayed backends' latency of the same topic.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.report.markup import escaped
from replaybench.report.svg import colour, step_cdf
from replaybench.results.numbers import finite_number
from replaybench.results.recorded_latency import recorded_times
from replaybench.textsafe import visible

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.results.model import SummaryRow
    from replaybench.results.records import FrameRecord

__all__ = ['recorded_latency_html', 'recorded_latency_lines']

#: (figure, name, what it spans), as the section and the terminal name them
FIGURES: tuple[tuple[str, str, str], ...] = (
    ('pipeline_ms', 'pipeline', 'image logged → output logged (recorder clock)'),
    (
        'capture_to_output_ms',
        'capture-to-output',
        'image stamped → output logged (camera and recorder clocks)',
    ),
)


def _ms(value: Any) -> str:
    number = finite_number(value)
    if number is None:
        return '–'
    return (
        f'{number:.3f}' if abs(number) < 1 else f'{number:.2f}' if number < 100 else f'{number:.1f}'
    )


def _ci(low: Any, high: Any) -> str:
    lo, hi = finite_number(low), finite_number(high)
    return '' if lo is None or hi is None else f'{_ms(lo)}–{_ms(hi)}'


def recorded_latency_lines(summaries: Sequence[SummaryRow]) -> list[tuple[str, bool]]:
    """For the terminal: a line per (backend, topic) replaying recorded outputs, and its note
    (a figure refused, no interval) as a warning; (text, is_warning) each."""
    out: list[tuple[str, bool]] = []
    for s in summaries:
        if s.recorded_outputs is None:
            continue
        hz = finite_number(s.recorded_output_hz)
        parts = [f'{s.recorded_outputs} outputs, {s.recorded_outputs_dropped} frame(s) without one']
        if hz is not None:
            parts[0] += f', {hz:.1f} Hz'
        for figure, name, _ in FIGURES:
            p50 = getattr(s, f'{figure}_p50')
            if p50 is None:
                continue
            ci = _ci(getattr(s, f'{figure}_p50_ci_low'), getattr(s, f'{figure}_p50_ci_high'))
            parts.append(
                f'{name} p50 {_ms(p50)} ms'
                + (f' [{ci}]' if ci else '')
                + f', p99 {_ms(getattr(s, f"{figure}_p99"))} ms'
            )
        where = f'{visible(s.backend)} {visible(s.topic)}'
        out.append((f'recorded latency of {where}: ' + '; '.join(parts), False))
        if s.recorded_latency_note:
            out.append((f'{where}: recorded latency: {s.recorded_latency_note}', True))
    return out


def _cell(value: str, numeric: bool = True) -> str:
    return f'<td class="n">{value}</td>' if numeric else f'<td>{value}</td>'


def _with_ci(value: Any, low: Any, high: Any) -> str:
    ci = _ci(low, high)
    text = escaped(_ms(value))
    if ci:
        text += f'<br><span class="muted ci">{escaped(ci)}</span>'
    return _cell(text)


def _swatch(colours: Mapping[str, str], backend: str) -> str:
    fill = escaped(colours.get(backend, '#777'))
    return f'<span class="swatch" style="background:{fill}"></span>'


def _recorded_rows(row: SummaryRow, colours: Mapping[str, str]) -> list[str]:
    out = []
    backend = row.backend or '?'
    for n, (figure, name, spans) in enumerate(FIGURES):
        counts = ['', '', '']
        if n == 0:
            hz = finite_number(row.recorded_output_hz)
            counts = [
                escaped(str(row.recorded_outputs)),
                escaped(str(row.recorded_outputs_dropped)),
                '–' if hz is None else f'{hz:.2f}',
            ]
        cells = [
            _cell(_swatch(colours, backend) + escaped(backend), numeric=False),
            _cell(f'<code>{escaped(row.topic or "?")}</code>', numeric=False),
            _cell(
                f'recorded {escaped(name)}<br><span class="muted">{escaped(spans)}</span>', False
            ),
            _with_ci(
                getattr(row, f'{figure}_p50'),
                getattr(row, f'{figure}_p50_ci_low'),
                getattr(row, f'{figure}_p50_ci_high'),
            ),
            _with_ci(
                getattr(row, f'{figure}_p99'),
                getattr(row, f'{figure}_p99_ci_low'),
                getattr(row, f'{figure}_p99_ci_high'),
            ),
            _cell(escaped(_ms(getattr(row, f'{figure}_max')))),
            *(_cell(c) for c in counts),
        ]
        out.append(f'<tr class="recorded">{"".join(cells)}</tr>')
    return out


def _replayed_row(row: SummaryRow, colours: Mapping[str, str]) -> str:
    backend = row.backend or '?'
    cells = [
        _cell(_swatch(colours, backend) + escaped(backend), numeric=False),
        _cell(f'<code>{escaped(row.topic or "?")}</code>', numeric=False),
        _cell(
            'replayed latency<br><span class="muted">frame released → output (this machine)</span>',
            numeric=False,
        ),
        _with_ci(row.latency_ms_p50, row.latency_ms_p50_ci_low, row.latency_ms_p50_ci_high),
        _with_ci(row.latency_ms_p99, row.latency_ms_p99_ci_low, row.latency_ms_p99_ci_high),
        _cell(escaped(_ms(row.latency_ms_max))),
        _cell(''),
        _cell(''),
        _cell(''),
    ]
    return f'<tr class="replayed">{"".join(cells)}</tr>'


def _cdf(
    topic: str,
    rows: Sequence[SummaryRow],
    frames: Sequence[FrameRecord],
    colours: Mapping[str, str],
) -> str:
    """The CDF of each recorded figure and of each replayed backend's latency on ``topic``."""
    series: list[tuple[str, str, list[float]]] = []
    extra = len(colours)
    for row in rows:
        backend = row.backend or '?'
        records = [
            r
            for r in frames
            if r.backend == backend and r.topic == topic and r.status == 'ok' and not r.warmup
        ]
        if row.recorded_outputs is None:
            values = [r.latency_ms for r in records if r.latency_ms is not None]
            series.append((f'{backend} replayed', colours.get(backend, '#777'), values))
            continue
        times = [recorded_times(r.log_time_ns, r.stamp_ns, r.output_log_time_ns) for r in records]
        for figure, name, _ in FIGURES:
            if getattr(row, f'{figure}_p50') is None:
                continue  # refused: no number, no curve
            values = [v for t in times if (v := getattr(t, figure)) is not None]
            series.append((f'{backend} {name}', colour(extra), values))
            extra += 1
    if not any(values for _, _, values in series):
        return ''
    return step_cdf(
        series, title=f'Recorded and replayed latency CDF · {topic}', x_label='latency (ms)'
    )


def recorded_latency_html(
    rows: Sequence[SummaryRow], frames: Sequence[FrameRecord], colours: Mapping[str, str]
) -> str:
    """The report's "Recorded latency" section; '' when no backend replays recorded outputs."""
    topics = [r.topic for r in rows if r.recorded_outputs is not None]
    if not topics:
        return ''
    head = (
        '<tr><th>backend</th><th>topic</th><th>latency</th><th class="n">p50 ms</th>'
        '<th class="n">p99 ms</th><th class="n">max ms</th><th class="n">outputs</th>'
        '<th class="n">without output</th><th class="n">output Hz</th></tr>'
    )
    body: list[str] = []
    notes: list[str] = []
    charts: list[str] = []
    for topic in dict.fromkeys(topics):
        on_topic = [r for r in rows if r.topic == topic]
        for row in on_topic:
            if row.recorded_outputs is not None:
                body += _recorded_rows(row, colours)
                if row.recorded_latency_note:
                    notes.append(
                        f'<li><b>{escaped(row.backend)}</b> <code>{escaped(topic)}</code>: '
                        f'{escaped(row.recorded_latency_note)}</li>'
                    )
        body += [_replayed_row(r, colours) for r in on_topic if r.recorded_outputs is None]
        chart = _cdf(topic, on_topic, frames, colours)
        if chart:
            charts.append(f'<div class="charts">{chart}</div>')
    intro = (
        'Outputs recorded in the bag were produced on the robot, not replayed here: their '
        'latency is read from the recording. Pipeline = output log time − image log time: the '
        "node's work and the difference in transport of the two messages (the recorder's own "
        'delay cancels); the figure to set beside a replayed latency. Capture-to-output = output '
        "log time − image header stamp: also the image's transport to the recorder and what "
        "the driver's stamp precedes; only meaningful when the camera's and the recorder's "
        "clocks agree. Replayed latency runs from a frame's release to its output on this "
        'machine, reading and decoding included. Under p50 and p99: the 95 % interval (block '
        'bootstrap; none under 20 frames).'
    )
    notes_html = f'<ul class="recorded-notes">{"".join(notes)}</ul>' if notes else ''
    return (
        '<h2 id="recorded-latency">Recorded latency</h2>'
        f'<p class="muted">{escaped(intro)}</p>'
        f'<div class="table-wrap"><table id="recorded-latency-table"><thead>{head}</thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>{notes_html}{"".join(charts)}'
    )
