"""report.html's resource use: CPU, memory and GPU per backend, table and charts."""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.report.formats import fmt, fmt_value, swatch
from replaybench.report.markup import escaped
from replaybench.report.plots import CHART_PIXELS
from replaybench.report.svg import TREND_POINTS, Series, line_chart
from replaybench.results.model import ResourceSummary
from replaybench.results.numbers import finite_number

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.results.model import ResourcePoint, RunResult

__all__ = ['resources_html']

#: (series key, chart title, y label) of the resource charts, drawn when some backend has data.
_RESOURCE_CHARTS: tuple[tuple[str, str, str], ...] = (
    ('cpu_percent', 'CPU use over time', 'CPU (% of one core)'),
    ('private_mb', 'Private memory over time', 'private memory (MiB)'),
    ('rss_mb', 'Resident memory over time', 'RSS (MiB)'),
    ('gpu_util', 'GPU utilisation over time', 'GPU utilisation (%)'),
    ('gpu_mem_mb', 'GPU memory used over time', 'GPU memory (MiB)'),
)


#: The figures of a resource summary that a sampler measured (the rest describe the sampler).
_MEASURED: tuple[str, ...] = (
    'cpu_percent_mean',
    'private_mb_peak',
    'mapped_mb_peak',
    'rss_mb_peak',
    'gpu_util_mean',
    'gpu_mem_mb_peak',
    'gpu_power_w_mean',
)


def _resource_entries(
    run: RunResult,
) -> list[tuple[str, ResourceSummary, tuple[ResourcePoint, ...]]]:
    entries = []
    for entry in run.backends:
        resources = entry.resources
        if resources is None:
            continue
        summary = resources.summary or ResourceSummary()
        if not resources.series and all(getattr(summary, k) is None for k in _MEASURED):
            continue  # sampled nothing
        label = entry.label or entry.name or '?'
        entries.append((label, summary, resources.series))
    return entries


def resources_html(run: RunResult, colours: Mapping[str, str]) -> str:
    """Per backend CPU, memory and GPU use, from run.json ``backends[i].resources``."""
    entries = _resource_entries(run)
    if not entries:
        return ''
    gpu = any(
        finite_number(getattr(s, k)) is not None
        for _, s, _ in entries
        for k in ('gpu_util_mean', 'gpu_mem_mb_peak', 'gpu_power_w_mean')
    )
    # private (anonymous) memory first, the mapped input apart; RSS for runs made before
    private = any(finite_number(s.private_mb_peak) is not None for _, s, _ in entries)
    memory = (
        [
            ('private_mb_peak', 'private peak MiB'),
            ('private_mb_mean', 'private mean MiB'),
            ('mapped_mb_peak', 'mapped input + libraries peak MiB'),
        ]
        if private
        else [('rss_mb_peak', 'RSS peak MiB'), ('rss_mb_mean', 'RSS mean MiB')]
    )
    head = ['backend', 'CPU % mean', 'CPU % max', *(title for _, title in memory)]
    if gpu:
        head += ['GPU util % mean', 'GPU mem peak MiB', 'GPU power W mean']
    head += ['samples', 'sampler cost']
    th = ''.join(
        f'<th>{escaped(h)}</th>' if i == 0 else f'<th class="n">{escaped(h)}</th>'
        for i, h in enumerate(head)
    )
    body = []
    gpu_names: list[str] = []
    for label, s, _ in entries:
        interval = finite_number(s.interval_s)
        cost = finite_number(s.overhead_ms_per_sample)
        share = finite_number(s.overhead_cpu_percent)
        cost_text = '–' if cost is None else f'{cost:.3f} ms/sample'
        if share is not None:
            cost_text += f', {share:.2f} % of a core'
        samples = fmt_value(s.samples)
        if interval is not None:
            samples += f' every {interval:g} s'
        cells = [
            f'<td>{swatch(colours, label)}{escaped(label)}</td>',
            f'<td class="n">{escaped(fmt(s.cpu_percent_mean, 1))}</td>',
            f'<td class="n">{escaped(fmt(s.cpu_percent_max, 1))}</td>',
            *(f'<td class="n">{escaped(fmt(getattr(s, key), 1))}</td>' for key, _ in memory),
        ]
        if gpu:
            cells += [
                f'<td class="n">{escaped(fmt(s.gpu_util_mean, 1))}</td>',
                f'<td class="n">{escaped(fmt(s.gpu_mem_mb_peak, 0))}</td>',
                f'<td class="n">{escaped(fmt(s.gpu_power_w_mean, 1))}</td>',
            ]
            name = s.gpu_name
            if name and name not in gpu_names:
                gpu_names.append(name)
        cells += [
            f'<td class="n">{escaped(samples)}</td>',
            f'<td class="n">{escaped(cost_text)}</td>',
        ]
        body.append(f'<tr>{"".join(cells)}</tr>')
    note = (
        'Sampled in a background thread while each backend ran. CPU is this process (every '
        'thread) in % of one core, so more than 100 means several cores. '
        + (
            'Private memory is what the process allocated (RssAnon: resident, not backed by a '
            'file); mapped is the resident part of memory-mapped files, the input bag and the '
            'loaded libraries, which the kernel reads back from disk and can drop at any time, '
            'so a large bag is not a leak.'
            if private
            else 'RSS is its resident memory, the memory-mapped input included.'
        )
    )
    if gpu:
        note += ' GPU numbers are for the whole device' + (
            f' ({", ".join(gpu_names)})' if gpu_names else ''
        )
        note += ', all processes on it.'
    charts = []
    for key, title, y_label in _RESOURCE_CHARTS:
        if key == ('rss_mb' if private else 'private_mb'):
            continue
        series = []
        for label, _, points in entries:
            pairs = [
                (p.t_s, y)
                for p in points
                if finite_number(p.t_s) is not None
                and (y := finite_number(getattr(p, key))) is not None
            ]
            if pairs:
                series.append(
                    Series(
                        label,
                        colours.get(label, '#777'),
                        [x for x, _ in pairs],
                        [y for _, y in pairs],
                    ),
                )
        if series:
            longest = max(len(s.xs) for s in series)
            charts.append(
                line_chart(
                    series,
                    title=title,
                    x_label='time since the backend started (s)',
                    y_label=y_label,
                    mean_per_pixel=True,
                    note='Each point is the mean over the samples of one pixel column.'
                    if longest > CHART_PIXELS
                    else '',
                    min_points=TREND_POINTS,
                ),
            )
    return (
        '<h2 id="resources">Resource use</h2>'
        f'<div class="table-wrap"><table><thead><tr>{th}</tr></thead>'
        f'<tbody>{"".join(body)}</tbody></table></div><p class="muted">{escaped(note)}</p>'
        + (f'<div class="charts">{"".join(charts)}</div>' if charts else '')
    )


# --------------------------------------------------------------------------- samples
