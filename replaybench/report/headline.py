"""The headline at the top of report.html: per topic, the fastest backend, the most accurate one
and how well the two agree, in one table narrow enough for a laptop screen.

* **Fastest**: the highest throughput (summary ``throughput_fps``) among the backends that
  detect; ``null`` (the harness alone) is a reference and is only named when it ran alone. A
  backend replaying recorded outputs (``recorded``) never competes: its FPS is how fast the bag
  was read, not how fast the robot's node ran (``results.recorded_latency.replays_recording``);
  with no replayed backend, no backend is the fastest. Its
  FPS, p50 and p99 latency come with the 95 % block-bootstrap intervals of its summary row, the
  ones run.json and summary.csv hold (``replaybench.results.intervals``, which also gives
  ``replaybench compare`` a row's own interval: the same intervals everywhere; none below
  ``MIN_FRAMES`` measured frames); a run.json without them gets the same computation on the
  row's frames. The same run folder gives the same page.
* **Most accurate**: the best by the topic's judging figure: the first registered task's main
  figure (``MetricSpec.main``, in the tasks' order: the boxes' mAP@0.5, then the tags' recall,
  the masks' mIoU, a task from an entry point's) that a row of the topic has, the highest or
  the lowest as the figure's ``better`` says; none without ground truth.
* **Agreement**: from run.json ``agreement``, the share of each of the two backends' detections
  that the other one matched, and their mean IoU.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from replaybench.report.markup import escaped
from replaybench.results.bootstrap import CONFIDENCE
from replaybench.results.intervals import measured_series, row_intervals
from replaybench.results.numbers import finite_number
from replaybench.results.recorded_latency import replays_recording

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import RunResult, SummaryRow
    from replaybench.results.records import FrameRecord
    from replaybench.tasks import MetricSpec

__all__ = ['Agreement', 'TopicHeadline', 'headline_html', 'topic_headlines']

#: Backends that measure the harness, not a detector: the fastest only when alone.
REFERENCE_BACKENDS = frozenset({'null'})

Interval = tuple[float, float]


@dataclass(frozen=True)
class Agreement:
    """How the fastest and the most accurate backend agree on one topic."""

    matched_fastest: float | None  # share of the fastest backend's detections matched
    matched_accurate: float | None  # share of the most accurate backend's detections matched
    mean_iou: float | None


@dataclass(frozen=True)
class TopicHeadline:
    """One row of the headline."""

    topic: str
    fastest: str | None
    #: the topic's rows replay recorded outputs only (none is timed here)
    recorded_only: bool
    fps: float | None
    fps_ci: Interval | None
    fps_all: float | None  # the fastest backend's FPS summed over every topic (several topics)
    p50_ms: float | None
    p50_ci: Interval | None
    p99_ms: float | None
    p99_ci: Interval | None
    measured: int
    accurate: str | None
    #: the most accurate backend's value of the judging figure
    accuracy: float | None
    agreement: Agreement | None
    #: the figure the most accurate backend was chosen by (None without ground truth)
    judged_by: MetricSpec | None = None


def _judges() -> list[MetricSpec]:
    """Each registered task's main figure, in the tasks' order."""
    from replaybench.tasks import get_task, task_names

    found: list[MetricSpec] = []
    for name in task_names():
        found += [m for m in get_task(name).metrics if m.main][:1]
    return found


def _most_accurate(
    rows: Sequence[SummaryRow], judges: Sequence[MetricSpec]
) -> tuple[SummaryRow | None, MetricSpec | None]:
    """The best row by the first of ``judges`` that a row has, and that figure."""
    for spec in judges:
        scored = [r for r in rows if r.metric(spec.name) is not None]
        if scored:
            sign = 1.0 if spec.better == 'higher' else -1.0
            return max(scored, key=lambda r: sign * (r.metric(spec.name) or 0.0)), spec
    return None, None


def _pair(low: float | None, high: float | None) -> Interval | None:
    lo, hi = finite_number(low), finite_number(high)
    return (lo, hi) if lo is not None and hi is not None else None


def _intervals(
    row: SummaryRow, records: Sequence[FrameRecord]
) -> tuple[Interval | None, Interval | None, Interval | None]:
    """The 95 % intervals of (FPS, p50, p99) of ``row``: those run.json holds, or where it
    holds none (a run.json written without them), the same computation on the row's frames."""
    held = (
        _pair(row.throughput_fps_ci_low, row.throughput_fps_ci_high),
        _pair(row.latency_ms_p50_ci_low, row.latency_ms_p50_ci_high),
        _pair(row.latency_ms_p99_ci_low, row.latency_ms_p99_ci_high),
    )
    if any(held):
        return held
    points = (
        finite_number(row.latency_ms_p50),
        finite_number(row.latency_ms_p99),
        finite_number(row.throughput_fps),
    )
    found = row_intervals(row.backend, row.topic, measured_series(records), points=points)
    return found.fps, found.p50, found.p99


def _agreement(run: RunResult, topic: str, fast: str, accurate: str) -> Agreement | None:
    for entry in run.agreement:
        if entry.topic != topic:
            continue
        a, b = entry.backend_a, entry.backend_b
        if (a, b) == (fast, accurate):
            frac_fast, frac_acc = entry.matched_frac_a, entry.matched_frac_b
        elif (a, b) == (accurate, fast):
            frac_fast, frac_acc = entry.matched_frac_b, entry.matched_frac_a
        else:
            continue
        return Agreement(
            finite_number(frac_fast), finite_number(frac_acc), finite_number(entry.mean_iou)
        )
    return None


def topic_headlines(
    run: RunResult, rows: Sequence[SummaryRow], frames: Sequence[FrameRecord]
) -> list[TopicHeadline]:
    """One headline per topic, in the order of the summary rows."""
    names: dict[str, str] = {}
    for entry in run.backends:
        label = entry.label or entry.name
        names[label] = entry.name or label
    by_topic: dict[str, list[SummaryRow]] = {}
    for row in rows:
        by_topic.setdefault(row.topic or '?', []).append(row)
    fps_all: dict[str, float] = {}
    for row in rows:
        fps = finite_number(row.throughput_fps)
        if fps is not None and not replays_recording(row):
            fps_all[row.backend] = fps_all.get(row.backend, 0.0) + fps
    groups: dict[tuple[str, str], list[FrameRecord]] = {}
    for record in frames:
        groups.setdefault((record.backend, record.topic), []).append(record)
    out = []
    judges = _judges()
    for topic, topic_rows in by_topic.items():
        replayed = [r for r in topic_rows if not replays_recording(r)]
        timed = [r for r in replayed if finite_number(r.throughput_fps) is not None]
        detectors = [r for r in timed if names.get(r.backend, '') not in REFERENCE_BACKENDS]
        pool = detectors or timed
        fastest = max(pool, key=lambda r: finite_number(r.throughput_fps) or 0.0, default=None)
        accurate, judged_by = _most_accurate(topic_rows, judges)
        fast_name = fastest.backend if fastest is not None else None
        acc_name = accurate.backend if accurate is not None else None
        fps_ci = p50_ci = p99_ci = None
        if fastest is not None:
            fps_ci, p50_ci, p99_ci = _intervals(fastest, groups.get((fastest.backend, topic), []))
        agreement = None
        if fast_name is not None and acc_name is not None and fast_name != acc_name:
            agreement = _agreement(run, topic, fast_name, acc_name)
        out.append(
            TopicHeadline(
                topic=topic,
                fastest=fast_name,
                recorded_only=not replayed,
                fps=finite_number(fastest.throughput_fps) if fastest is not None else None,
                fps_ci=fps_ci,
                fps_all=fps_all.get(fast_name) if fast_name and len(by_topic) > 1 else None,
                p50_ms=finite_number(fastest.latency_ms_p50) if fastest is not None else None,
                p50_ci=p50_ci,
                p99_ms=finite_number(fastest.latency_ms_p99) if fastest is not None else None,
                p99_ci=p99_ci,
                measured=fastest.measured if fastest is not None else 0,
                accurate=acc_name,
                accuracy=None
                if accurate is None or judged_by is None
                else accurate.metric(judged_by.name),
                agreement=agreement,
                judged_by=judged_by,
            )
        )
    return out


# --------------------------------------------------------------------------- HTML


def _fmt(value: float | None, digits: int) -> str:
    return '–' if value is None else f'{value:.{digits}f}'


def _ms_digits(value: float | None) -> int:
    return 3 if value is not None and value < 1 else 2 if value is not None and value < 100 else 1


def _with_interval(value: float | None, interval: Interval | None, digits: int) -> str:
    text = f'<b>{escaped(_fmt(value, digits))}</b>'
    if interval is not None:
        lo, hi = interval
        text += (
            f'<br><span class="muted">{escaped(_fmt(lo, digits))}–'
            f'{escaped(_fmt(hi, digits))}</span>'
        )
    return text


def _share(value: float | None) -> str:
    return '–' if value is None else f'{100 * value:.0f} %'


def _agreement_cell(head: TopicHeadline) -> str:
    if head.fastest is None or head.accurate is None:
        return '<span class="muted">–</span>'
    if head.fastest == head.accurate:
        return '<span class="muted">one backend is both</span>'
    found = head.agreement
    if found is None:
        return '<span class="muted">not measured</span>'
    iou = f', IoU {found.mean_iou:.2f}' if found.mean_iou is not None else ''
    return (
        f'{escaped(_share(found.matched_fastest))} of {escaped(head.fastest)}’s boxes, '
        f'{escaped(_share(found.matched_accurate))} of {escaped(head.accurate)}’s matched'
        f'{escaped(iou)}'
    )


_CSS = (
    '#headline-table{table-layout:fixed;width:100%}'
    '#headline-table td,#headline-table th{overflow-wrap:anywhere;white-space:normal}'
    '#headline-table col.topic{width:17%}#headline-table col.backend{width:10%}'
    '#headline-table col.fps{width:12%}#headline-table col.ms{width:9%}'
    '#headline-table col.map{width:8%}#headline-table col.agree{width:25%}'
    '#headline-table.timed col.topic{width:34%}#headline-table.timed col.backend{width:24%}'
    '#headline-table.timed col.fps{width:16%}#headline-table.timed col.ms{width:13%}'
)


def headline_html(run: RunResult, rows: Sequence[SummaryRow], frames: Sequence[FrameRecord]) -> str:
    """The headline section, or '' when no row was measured."""
    heads = topic_headlines(run, rows, frames)
    if not heads or all(h.fastest is None and h.accurate is None for h in heads):
        return ''
    many = len(heads) > 1
    scored = any(h.accuracy is not None for h in heads)
    figures = list(dict.fromkeys(h.judged_by for h in heads if h.judged_by is not None))
    # one figure for every topic: its label heads the column; several: each cell names its own
    one = figures[0] if len(figures) == 1 else None
    level = f'{CONFIDENCE * 100:.0f} %'
    body = []
    for head in heads:
        fps = _with_interval(head.fps, head.fps_ci, 1)
        p50 = _with_interval(head.p50_ms, head.p50_ci, _ms_digits(head.p50_ms))
        p99 = _with_interval(head.p99_ms, head.p99_ci, _ms_digits(head.p99_ms))
        if head.fps_all is not None:
            fps += f'<br><span class="muted">of {escaped(_fmt(head.fps_all, 1))} in all</span>'
        cells = [
            f'<td><code>{escaped(head.topic).replace("/", "/<wbr>")}</code></td>',
            f'<td>{escaped(head.fastest or "–")}</td>'
            if head.fastest or not head.recorded_only
            else '<td><span class="muted">none replayed: recorded outputs only</span></td>',
            f'<td class="n">{fps}</td>',
            f'<td class="n">{p50}</td>',
            f'<td class="n">{p99}</td>',
        ]
        if scored:
            cells += [
                f'<td>{escaped(head.accurate or "no ground truth")}</td>',
                f'<td class="n"><b>{escaped(_fmt(head.accuracy, 3))}</b>'
                + (
                    f'<br><span class="muted">{escaped(head.judged_by.short_label)}</span>'
                    if one is None and head.judged_by is not None
                    else ''
                )
                + '</td>',
                f'<td>{_agreement_cell(head)}</td>',
            ]
        body.append(f'<tr>{"".join(cells)}</tr>')
    cols = (
        '<col class="topic"><col class="backend"><col class="fps"><col class="ms"><col class="ms">'
    )
    head_row = (
        '<th>topic</th><th>fastest</th><th class="n">FPS</th><th class="n">p50 ms</th>'
        '<th class="n">p99 ms</th>'
    )
    if scored:
        cols += '<col class="backend"><col class="map"><col class="agree">'
        label = one.label if one is not None else 'accuracy'
        head_row += (
            f'<th>most accurate</th><th class="n">{escaped(label)}</th>'
            '<th>agreement of the two</th>'
        )
    notes = [
        (
            f'Under each figure of the fastest backend, its {level} interval (block bootstrap '
            'of the measured frames, as in replaybench compare; none under 20 measured frames). '
            'null, the harness alone, is left out of "fastest" unless it ran alone.'
        )
    ]
    recordings = ', '.join(dict.fromkeys(r.backend for r in rows if replays_recording(r)))
    if recordings:
        notes[0] += (
            f' {recordings}: the outputs recorded in the bag, which never compete on speed (the '
            'rate such a backend is replayed at is how fast the bag was read, not how fast the '
            "robot's node ran; its recorded output rate and latency are in the Summary and "
            'under Recorded latency).'
        )
    if scored:
        named = ', '.join(spec.label for spec in figures)
        notes[0] += (
            f' Most accurate: by {named} against the ground truth; agreement: share of each '
            'backend’s detections the other matched '
            f'(IoU ≥ {run.settings.agreement_iou:g}, same class).'
        )
    else:
        notes.append(
            'No ground truth in this run, so no accuracy: give a ground-truth topic '
            '(--ground-truth) or file (--ground-truth-file).'
        )
    if many:
        notes.append(
            'FPS with several topics: a topic’s measured frames per second of the backend’s '
            'processing window. The topics are replayed together, interleaved, so they share '
            'that window and each topic gets a part of it: "in all" is the backend’s rate over '
            'every topic, the sum of its topics’ FPS.'
        )
    return (
        f'<style>{_CSS}</style><h2 id="headline">Headline</h2>'
        f'<table id="headline-table" class="{"scored" if scored else "timed"}">'
        f'<colgroup>{cols}</colgroup><thead><tr>{head_row}</tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table>'
        + ''.join(f'<p class="muted">{escaped(note)}</p>' for note in notes)
    )
