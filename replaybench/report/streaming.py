"""report.html's "Streaming scores" section: per backend and topic, each streaming score beside
the offline figure it is the streaming form of, and the output age as a distribution
(``replaybench.results.streaming``; docs/streaming.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.markup import escaped, number_text
from replaybench.results.streaming import output_ages, streaming_pairs

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.results.model import SummaryRow
    from replaybench.results.records import FrameRecord

__all__ = ['streaming_html']

_INTRO = (
    'Offline, each output is scored against the truth of the frame it was computed from, as if '
    'the world had waited. Streaming, every frame with truth is scored against the output that '
    "was the latest finished at the frame's release (on the replay clock; for recorded outputs, "
    'at their log times), whichever frame that output came from; before the first output, '
    "against none. Output age: the frame's release time minus the release time of the frame "
    'the output in use came from.'
)


def _ages(records: Sequence[FrameRecord], backend: str, topic: str) -> str:
    """The output ages of a (backend, topic)'s frames, as counts by age (ms, to the ms)."""
    counts: dict[int, int] = {}
    none = 0
    for r in records:
        if r.repeat or r.backend != backend or r.topic != topic:
            continue
        if r.output_age_ms is None:
            none += 1
        else:
            age = round(r.output_age_ms)
            counts[age] = counts.get(age, 0) + 1
    most = max([*counts.values(), none, 1])
    bars = [
        f'<tr><td class="n">{age} ms</td><td class="n">{n}</td>'
        f'<td><span class="bar" style="display:inline-block;height:0.8em;background:#888;'
        f'width:{100 * n / most:.1f}px"></span></td></tr>'
        for age, n in sorted(counts.items())
    ]
    if none:
        bars.append(f'<tr><td class="n">no output yet</td><td class="n">{none}</td><td></td></tr>')
    return f'<table class="streaming-ages"><tbody>{"".join(bars)}</tbody></table>'


def streaming_html(
    rows: Sequence[SummaryRow],
    records: Sequence[FrameRecord],
    offline_of: Mapping[str, tuple[str, str]],
) -> str:
    """The section; '' where no row has streaming scores. ``offline_of``: streaming metric ->
    (its label, its offline figure), ``replaybench.tasks.streaming_offline``."""
    ages = output_ages(records)
    body: list[str] = []
    for row in rows:
        pairs = streaming_pairs(row, offline_of)
        if not pairs:
            continue
        spread = ages.get((row.backend, row.topic))
        age = (
            f'p50 {spread.p50_ms:.1f} ms, p90 {spread.p90_ms:.1f} ms, max {spread.max_ms:.1f} ms'
            if spread is not None
            else '–'
        )
        first = True
        for pair in pairs:
            where = (
                f'<td rowspan="{len(pairs)}">{escaped(row.backend)}</td>'
                f'<td rowspan="{len(pairs)}"><code>{escaped(row.topic)}</code></td>'
                if first
                else ''
            )
            shown = (
                f'<td rowspan="{len(pairs)}">{escaped(age)}'
                f'{_ages(records, row.backend, row.topic)}</td>'
                if first
                else ''
            )
            body.append(
                f'<tr>{where}<td>{escaped(pair.label.removeprefix("streaming "))}</td>'
                f'<td class="n">{number_text(pair.offline_value, ".3f")}</td>'
                f'<td class="n">{number_text(pair.value, ".3f")}</td>'
                f'<td class="n">{pair.change:+.3f}</td>{shown}</tr>'
            )
            first = False
    if not body:
        return ''
    head = (
        '<tr><th>backend</th><th>topic</th><th>figure</th><th class="n">offline</th>'
        '<th class="n">streaming</th><th class="n">difference</th><th>output age</th></tr>'
    )
    return (
        '<h2 id="streaming">Streaming scores</h2>'
        f'<p class="muted">{escaped(_INTRO)}</p>'
        f'<div class="table-wrap"><table id="streaming-table"><thead>{head}</thead>'
        f'<tbody>{"".join(body)}</tbody></table></div>'
    )
