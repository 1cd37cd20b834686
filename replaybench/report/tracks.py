"""The report's Tracking section: each tracked row's id-switch timeline, an inline SVG.

x: the frames of the row's scored sequence (its processed frames with truth, in replay order,
from 0); one lane per truth object (ids in order), each frame it is matched coloured by the
track it is matched to (CLEAR's matching, ``replaybench.tracking.clear_matching``: the one
that counts ``id_switches``), a dashed line where it is in the truth but missed, nothing where
it is not in the truth; a marked tick (class ``idsw``, its tooltip the frame, the object and
the two track ids) at each ID switch. At most ``MAX_LANES`` lanes: those of the objects with
the most switches, the others counted under the chart.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.colours import colour
from replaybench.report.markup import escaped
from replaybench.report.svg import fit_label, nice_ticks
from replaybench.report.svg.parts import AXIS, CHAR_W, GRID, TEXT, coord, svg_open, tick_text

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import SummaryRow, TrackLane, TrackTimeline

__all__ = ['MAX_LANES', 'timeline_svg', 'track_timelines_html']

#: the most lanes (truth objects) a timeline shows: those with the most ID switches
MAX_LANES = 40

_WIDTH = 720
_LEFT = 92
_RIGHT = 64
_TOP = 72
_LANE = 16
_BAR = 10
_SWITCH = '#c00000'
_KEY = (
    'bar: matched, one colour per track id · dashed: in the truth, missed · red tick: an ID switch'
)
_INTRO = (
    '<p class="muted">ID switches over each tracked row&#x27;s scored sequence (its processed '
    'frames with truth, in replay order): one lane per truth object, coloured by the track '
    'CLEAR matched it to (IoU ≥ 0.5, keeping the previous frame&#x27;s pair), dashed where it '
    'was missed; a red tick where it was matched to another track than at its last match, '
    'each one counted in <code>id_switches</code> (docs/tracking.md).</p>'
)


def _shown(timeline: TrackTimeline) -> list[TrackLane]:
    """The lanes shown, in id order: the ``MAX_LANES`` objects with the most switches (ties:
    the first in id order)."""
    if len(timeline.lanes) <= MAX_LANES:
        return list(timeline.lanes)
    counts: dict[str, int] = {}
    for event in timeline.switches:
        counts[event.object_id] = counts.get(event.object_id, 0) + 1
    order = sorted(
        range(len(timeline.lanes)), key=lambda i: -counts.get(timeline.lanes[i].object_id, 0)
    )
    keep = sorted(order[:MAX_LANES])
    return [timeline.lanes[i] for i in keep]


def _track_colours(timeline: TrackTimeline) -> dict[str, str]:
    """A colour per track id, in order of the tracks' first match."""
    first: dict[str, int] = {}
    for lane in timeline.lanes:
        for span in lane.spans:
            if span.track_id is not None:
                first[span.track_id] = min(first.get(span.track_id, span.first), span.first)
    ordered = sorted(first, key=lambda t: (first[t], t))
    return {track: colour(i) for i, track in enumerate(ordered)}


def timeline_svg(backend: str, topic: str, timeline: TrackTimeline) -> str:
    """The id-switch timeline of one (backend, topic) row as an inline SVG."""
    lanes = _shown(timeline)
    shown_ids = {lane.object_id for lane in lanes}
    switches = [e for e in timeline.switches if e.object_id in shown_ids]
    colours = _track_colours(timeline)
    frames = max(timeline.frames, 1)
    plot_w = _WIDTH - _LEFT - _RIGHT
    step = plot_w / frames
    height = _TOP + max(len(lanes), 1) * _LANE + 44
    base = _TOP + len(lanes) * _LANE

    def x(frame: float) -> float:
        return _LEFT + frame * step

    seqs = timeline.seqs if len(timeline.seqs) == timeline.frames else ()

    def seq_of(frame: int) -> str:
        """`` (seq S)``: frames.csv's seq of a frame of the sequence, where known."""
        return f' (seq {seqs[frame]})' if seqs else ''

    title = f'ID switches · {backend} · {topic}'
    total = len(timeline.switches)
    legend = f'{total} ID switch{"" if total == 1 else "es"} (id_switches in summary.csv)'
    parts = [
        svg_open(_WIDTH, height, title).replace(
            '<svg class="chart"',
            f'<svg class="chart track-timeline" data-backend="{escaped(backend)}" '
            f'data-topic="{escaped(topic)}" data-switches="{total}"',
            1,
        ),
        f'<text class="legend" x="8" y="38" fill="{TEXT}">{escaped(legend)}</text>',
        f'<text x="8" y="54" fill="#666">{escaped(_KEY)}</text>',
    ]
    ticks = [t for t in nice_ticks(0.0, float(timeline.frames)) if 0 <= t <= timeline.frames]
    for tick in ticks:
        px = x(tick)
        parts.append(
            f'<line x1="{coord(px)}" y1="{_TOP - 4}" x2="{coord(px)}" y2="{coord(base + 4)}" '
            f'stroke="{GRID}"/>'
            f'<text x="{coord(px)}" y="{coord(base + 17)}" text-anchor="middle" fill="{TEXT}">'
            f'{escaped(tick_text(tick, ticks))}</text>'
        )
    parts.append(
        f'<text x="{coord(_LEFT + plot_w / 2)}" y="{coord(base + 34)}" text-anchor="middle" '
        f'fill="{TEXT}">frame of the scored sequence (replay order, from 0)</text>'
    )
    by_lane: dict[str, int] = {}
    for event in switches:
        by_lane[event.object_id] = by_lane.get(event.object_id, 0) + 1
    label_chars = int((_LEFT - 12) / CHAR_W)
    for row, lane in enumerate(lanes):
        top = _TOP + row * _LANE
        mid = top + _LANE / 2
        name = f'object {lane.object_id}'
        label = fit_label(name, label_chars)
        tip = f'<title>{escaped(name)}</title>' if label != name else ''
        parts.append(
            f'<text x="{_LEFT - 6}" y="{coord(mid + 4)}" text-anchor="end" fill="{TEXT}">'
            f'{tip}{escaped(label)}</text>'
        )
        for span in lane.spans:
            x0, x1 = x(span.first), x(span.last + 1)
            frames_text = (
                f'frame {span.first}{seq_of(span.first)}'
                if span.first == span.last
                else f'frames {span.first}–{span.last}'
                + (f' (seq {seqs[span.first]}–{seqs[span.last]})' if seqs else '')
            )
            if span.track_id is None:
                parts.append(
                    f'<line class="missed" x1="{coord(x0)}" y1="{coord(mid)}" x2="{coord(x1)}" '
                    f'y2="{coord(mid)}" stroke="#999" stroke-dasharray="2 2">'
                    f'<title>object {escaped(lane.object_id)} missed, {frames_text}</title>'
                    '</line>'
                )
                continue
            parts.append(
                f'<rect class="matched" x="{coord(x0)}" y="{coord(mid - _BAR / 2)}" '
                f'width="{coord(max(x1 - x0, 0.5))}" height="{_BAR}" '
                f'fill="{colours[span.track_id]}">'
                f'<title>object {escaped(lane.object_id)}: track {escaped(span.track_id)}, '
                f'{frames_text}</title></rect>'
            )
        count = by_lane.get(lane.object_id, 0)
        if count:
            parts.append(
                f'<text x="{_WIDTH - _RIGHT + 6}" y="{coord(mid + 4)}" fill="{_SWITCH}">'
                f'{count} IDSW</text>'
            )
    rows = {lane.object_id: row for row, lane in enumerate(lanes)}
    for event in switches:
        top = _TOP + rows[event.object_id] * _LANE
        px = x(event.frame)
        parts.append(
            f'<g class="idsw"><title>frame {event.frame}{seq_of(event.frame)}: '
            f'object {escaped(event.object_id)}, '
            f'track {escaped(event.from_id)} → {escaped(event.to_id)}</title>'
            f'<line x1="{coord(px)}" y1="{coord(top + 1)}" x2="{coord(px)}" '
            f'y2="{coord(top + _LANE - 1)}" stroke="{_SWITCH}" stroke-width="2"/>'
            f'<path d="M{coord(px - 4)} {coord(top)}h8l-4 5z" fill="{_SWITCH}"/></g>'
        )
    parts.append(
        f'<line x1="{_LEFT}" y1="{coord(base)}" x2="{_LEFT + plot_w}" y2="{coord(base)}" '
        f'stroke="{AXIS}"/></svg>'
    )
    return ''.join(parts)


def _hidden_note(timeline: TrackTimeline, shown: int) -> str:
    hidden = len(timeline.lanes) - shown
    if hidden <= 0:
        return ''
    kept = {lane.object_id for lane in _shown(timeline)}
    switches = sum(1 for e in timeline.switches if e.object_id not in kept)
    return (
        f'<p class="muted">{hidden} of {len(timeline.lanes)} objects not shown (the '
        f'{MAX_LANES} with the most ID switches are); {switches} of the ID switches are '
        'theirs.</p>'
    )


def track_timelines_html(rows: Sequence[SummaryRow]) -> str:
    """The Tracking section: a timeline per row that has one; a line for a row with tracking
    figures but none (a run.json written before timelines were kept); '' when no row has
    tracking figures."""
    with_figures = [
        r for r in rows if r.track_timeline is not None or r.metric('id_switches') is not None
    ]
    if not with_figures:
        return ''
    parts = ['<h2 id="tracking">Tracking</h2>', _INTRO]
    for row in with_figures:
        timeline = row.track_timeline
        if timeline is None:
            switches = row.metric('id_switches')
            parts.append(
                f'<p class="muted">{escaped(row.backend)} · <code>{escaped(row.topic)}</code>: '
                f'{_count(switches)} ID switches; no timeline (its run.json was written '
                'before replaybench kept one).</p>'
            )
            continue
        parts.append(f'<div class="charts">{timeline_svg(row.backend, row.topic, timeline)}</div>')
        parts.append(_hidden_note(timeline, len(_shown(timeline))))
    return ''.join(parts)


def _count(value: float | None) -> str:
    """A count as text ('–' for none)."""
    return '–' if value is None else f'{value:.0f}'
