"""report.html: one self-contained page (inline CSS, inline SVG, embedded images) per run folder.

The page is put together here from its sections, each in its module: the header, warnings and
cards (``cards``), the headline (``headline``), the Summary (``summary``), recorded latency
(``recorded``), the charts (``plots``), agreement (``agreement``), resource use
(``resources``), the samples (``gallery``) and the run's details (``details``). Each registered
task adds its parts (``taskviews``): its main figure and columns in the Summary, a panel under
it (the boxes' average precision per class) and a section after the recorded latency (tag
accuracy).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.agreement import agreement_html
from replaybench.report.cards import (
    banner_html,
    environment_html,
    header_html,
    inputs_html,
    settings_html,
)
from replaybench.report.details import details_html, footer_html
from replaybench.report.gallery import samples_html
from replaybench.report.headline import headline_html
from replaybench.report.markup import escaped
from replaybench.report.page import page_html
from replaybench.report.plots import plots_html
from replaybench.report.recorded import recorded_latency_html
from replaybench.report.resources import resources_html
from replaybench.report.rig import rig_html
from replaybench.report.summary import summary_html
from replaybench.report.svg import colour
from replaybench.report.taskviews import report_parts
from replaybench.results.atomic import write_text_atomic
from replaybench.results.folder import load_run
from replaybench.results.intervals import with_intervals
from replaybench.results.recorded_latency import with_recorded_latency
from replaybench.results.rig import is_rig, with_rig_rows
from replaybench.results.stats import summarize

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from replaybench.results.folder import RunData
    from replaybench.results.model import RunResult, SummaryRow
    from replaybench.results.records import FrameRecord

__all__ = ['render_html', 'render_report']


def _backend_order(run: RunResult, frames: Sequence[FrameRecord]) -> list[str]:
    order: list[str] = []
    for entry in run.backends:
        label = entry.label or entry.name
        if label and label not in order:
            order.append(label)
    for record in frames:
        if record.backend not in order:
            order.append(record.backend)
    return order


def _topic_order(frames: Sequence[FrameRecord], rows: Sequence[SummaryRow]) -> list[str]:
    order: list[str] = []
    for topic in [r.topic for r in frames] + [r.topic for r in rows]:
        if topic not in order:
            order.append(topic)
    return order


def _summary_rows(run: RunResult, frames: Sequence[FrameRecord]) -> list[SummaryRow]:
    """run.json's summary rows; where it has none, those computed from frames.csv as the run
    would have written them, intervals and warnings included (throttling aside: that needs the
    resource samples)."""
    if run.summary_rows:
        return list(run.summary_rows)
    rows = with_recorded_latency(with_intervals(summarize(frames), frames), frames)
    return with_rig_rows(rows, frames)


def _streaming(rows: Sequence[SummaryRow], frames: Sequence[FrameRecord]) -> str:
    """The "Streaming scores" section (``replaybench.report.streaming``); '' without any."""
    if not any(r.task_metrics for r in rows):
        return ''
    from replaybench.report.streaming import streaming_html
    from replaybench.tasks import streaming_offline

    return streaming_html(rows, frames, streaming_offline())


# --------------------------------------------------------------------------- header


def render_html(data: RunData) -> str:
    """The report page of a loaded run folder."""
    run, frames = data.run, data.frames
    rows = _summary_rows(run, frames)
    # the rig rows (all of a backend's cameras) are in the Summary table and the Rig section;
    # the per-topic parts (headlines, charts, the tasks' panels) take the camera rows only
    cameras = [r for r in rows if not is_rig(r)]
    backends = _backend_order(run, frames)
    for row in rows:
        backend = row.backend or '?'
        if backend not in backends:
            backends.append(backend)
    colours = {b: colour(i) for i, b in enumerate(backends)}
    topics = _topic_order(frames, cameras)
    status = run.status
    parts = report_parts()
    body = [
        header_html(run),
        banner_html(run, frames, cameras),
        headline_html(run, cameras, frames),
        '<div class="cards">',
        inputs_html(run),
        environment_html(run.environment),
        settings_html(run),
        '</div>',
        '<h2 id="summary">Summary</h2>',
        summary_html(rows, colours, parts),
        *(panel(cameras) for panel in parts.summary_panels),
        recorded_latency_html(cameras, frames, colours),
        _streaming(cameras, frames),
        *(section(cameras) for section in parts.sections),
        plots_html(frames, cameras, backends, topics, colours),
        rig_html(run, frames),
        agreement_html(run, colours),
        resources_html(run, colours),
        samples_html(run, data.dir),
        details_html(run),
        footer_html(run),
    ]
    return page_html(f'replaybench report · {escaped(status)}', ''.join(body))


def render_report(run_dir: str | Path) -> Path:
    """Write ``run_dir/report.html`` (atomically) from the run folder and return its path."""
    data = load_run(run_dir)
    out = data.dir / 'report.html'
    write_text_atomic(out, render_html(data))
    return out
