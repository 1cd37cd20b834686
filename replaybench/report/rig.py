"""report.html's Rig section: a run replaying several camera topics of an input, per backend:
its rig row's figures, its worst cameras, and each camera's latency over time on one chart."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.colours import colour
from replaybench.report.formats import fmt_fps, fmt_ms
from replaybench.report.markup import escaped
from replaybench.report.plots import latency_timeline
from replaybench.results.repeats import one_timeline

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import RigBackend, RunResult, WorstCamera
    from replaybench.results.records import FrameRecord

__all__ = ['rig_html']


def _rate(value: float | None) -> str:
    return '–' if value is None else f'{value * 100:.1f} %'


def _worst(found: WorstCamera | None, text: str) -> str:
    if found is None:
        return '<span class="muted">none</span>'
    return f'<code>{escaped(found.topic)}</code> {text}'


def _row(rig: RigBackend) -> str:
    worst_p99 = _worst(rig.worst_p99, fmt_ms(rig.worst_p99.value) if rig.worst_p99 else '')
    worst_drop = _worst(
        rig.worst_drop_rate, _rate(rig.worst_drop_rate.value) if rig.worst_drop_rate else ''
    )
    return (
        f'<tr><td>{escaped(rig.backend)}</td><td class="n">{len(rig.cameras)}</td>'
        f'<td class="n">{rig.pipelines}</td><td class="n">{rig.frames}</td>'
        f'<td class="n">{rig.dropped}</td><td class="n">{_rate(rig.drop_rate)}</td>'
        f'<td class="n">{fmt_ms(rig.latency_ms_p99)}</td>'
        f'<td class="n">{fmt_fps(rig.throughput_fps)}</td>'
        f'<td>{worst_p99}</td><td>{worst_drop}</td></tr>'
    )


def rig_html(run: RunResult, frames: Sequence[FrameRecord]) -> str:
    """The Rig section ('' for a run without a rig): a table of each backend's rig (run.json's
    ``rig``) and, per backend, one chart of every camera's latency over time."""
    rig = run.rig
    if rig is None or not rig.backends:
        return ''
    parts = [
        '<h2 id="rig">Rig</h2>',
        (
            '<p class="muted">Each backend over all its cameras (<code>--pipelines '
            f"{escaped(rig.mode)}</code>, {rig.cores} core(s)): the summary's "
            '<code>rig</code> row, and the camera with the highest p99 latency and the one '
            'with the highest drop rate.</p>'
        ),
        (
            '<div class="table-wrap"><table id="rig-table"><thead><tr><th>backend</th>'
            '<th class="n">cameras</th><th class="n">pipelines</th><th class="n">frames</th>'
            '<th class="n">dropped</th><th class="n">drop rate</th><th class="n">p99 ms</th>'
            '<th class="n">FPS</th><th>worst p99</th><th>worst drop rate</th></tr></thead>'
            '<tbody>'
        ),
        *(_row(b) for b in rig.backends),
        '</tbody></table></div>',
    ]
    for backend in rig.backends:
        topics = [c.topic for c in backend.cameras]
        groups: dict[str, list[FrameRecord]] = {t: [] for t in topics}
        for record in frames:
            if record.backend == backend.backend and record.topic in groups:
                groups[record.topic].append(record)
        timelines = {t: one_timeline(rs) for t, rs in groups.items() if rs}
        if not timelines:
            continue
        colours = {t: colour(i) for i, t in enumerate(topics)}
        chart = latency_timeline(f'{backend.backend} · every camera', timelines, colours)
        parts.append(f'<div class="charts">{chart}</div>')
    return ''.join(parts)
