"""report.html's header, warnings banner and cards (inputs, machine, settings)."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from replaybench.report.formats import definition_list, fmt_bytes, fmt_value
from replaybench.report.markup import escaped
from replaybench.results.io import to_json
from replaybench.results.numbers import finite_number

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import Environment, RunResult, SummaryRow
    from replaybench.results.records import FrameRecord

__all__ = ['banner_html', 'environment_html', 'header_html', 'inputs_html', 'settings_html']


def header_html(run: RunResult) -> str:
    status = run.status
    meta = [
        f'<span class="badge {escaped(status)}">{escaped(status)}</span>',
        f'started {escaped(run.started_at or "?")}',
    ]
    wall = finite_number(run.wall_s)
    if wall is not None:
        meta.append(f'wall time {wall:.1f} s')
    meta.append(f'{escaped(run.tool.name)} {escaped(run.tool.version or "?")}')
    return f'<header><h1>replaybench report</h1><p class="meta">{" · ".join(meta)}</p></header>'


def banner_html(run: RunResult, frames: Sequence[FrameRecord], rows: Sequence[SummaryRow]) -> str:
    items: list[str] = []
    status = run.status
    if status == 'interrupted':
        items.append(
            'The run was interrupted: the numbers cover only the frames processed before it '
            'stopped.',
        )
    elif status != 'complete':
        items.append(f'The run ended with status {escaped(status)}.')
    for entry in run.inputs:
        path = escaped(entry.path or '?')
        if entry.truncated:
            items.append(
                f'Input <code>{path}</code> is truncated: only its complete messages were '
                'replayed.',
            )
        items.extend(f'<code>{path}</code>: {escaped(warning)}' for warning in entry.warnings)
    skipped = dict(run.skipped)
    n_skipped = sum(1 for r in frames if r.status == 'skipped')
    if skipped or n_skipped:
        reasons = ''.join(
            f'<li>{escaped(reason)}: {escaped(count)}</li>'
            for reason, count in sorted(skipped.items())
        )
        total = sum(skipped.values()) or n_skipped
        items.append(
            f'{total} frame(s) were skipped because they could not be decoded'
            + (f'<ul>{reasons}</ul>' if reasons else '.'),
        )
    items += [escaped(warning) for warning in run.warnings]
    for row in rows:
        where = f'<b>{escaped(row.backend or "?")}</b> <code>{escaped(row.topic or "?")}</code>'
        items += [f'{where}: {escaped(warning)}' for warning in row.warnings]
    if not items:
        return ''
    body = ''.join(f'<li>{item}</li>' for item in items)
    return f'<div class="banner" role="alert"><strong>Warnings</strong><ul>{body}</ul></div>'


def inputs_html(run: RunResult) -> str:
    rows = []
    for entry in run.inputs:
        sha = entry.sha256 or ''
        topics = ', '.join(t.name or '?' for t in entry.topics)
        flags = ' (truncated)' if entry.truncated else ''
        rows.append(
            f'<tr><td class="n">{escaped(entry.index)}</td>'
            f'<td><code>{escaped(entry.path or "?")}</code>{escaped(flags)}'
            f'<br><span class="muted">{escaped(topics)}</span></td>'
            f'<td>{escaped(entry.format or "")}</td>'
            f'<td class="n">{escaped(fmt_bytes(entry.size_bytes))}</td>'
            f'<td><code title="{escaped(sha)}">{escaped(sha[:12])}</code></td></tr>',
        )
    table = (
        '<table><thead><tr><th class="n">#</th><th>path / topics</th><th>format</th>'
        f'<th class="n">size</th><th>sha256</th></tr></thead><tbody>{"".join(rows)}</tbody>'
        '</table>'
    )
    return f'<div class="card"><h3>Inputs</h3>{table}</div>'


def environment_html(env: Environment) -> str:
    cpu, os_info, python, packages = env.cpu, env.os, env.python, env.packages
    opencv = packages.opencv
    gpus = [
        f'{g.name or "?"} ({g.memory_total or "?"}, driver {g.driver_version or "?"})'
        for g in env.gpus
    ]
    versions = [
        f'{f.name} {getattr(packages, f.name)}'
        for f in dataclasses.fields(packages)
        if isinstance(getattr(packages, f.name), str)
    ]
    if opencv.version:
        threads = opencv.threads if opencv.threads is not None else '?'
        versions.append(f'opencv {opencv.version} ({threads} threads)')
    cores, usable = cpu.logical_cores, cpu.usable_cores
    core_text = f'{cores}' + (f' ({usable} usable)' if usable not in (None, cores) else '')
    load = env.load_average
    items: list[tuple[str, Any]] = [
        ('host', env.hostname),
        ('CPU', cpu.model),
        ('cores', core_text),
        ('governor', cpu.governor),
        ('memory', fmt_bytes(env.memory_total_bytes)),
        ('GPUs', '; '.join(gpus) if gpus else 'none found'),
        ('OS', os_info.platform or os_info.system),
        ('Python', f'{python.implementation or ""} {python.version or ""}'.strip()),
        ('packages', ', '.join(versions)),
        ('load average', ' '.join(fmt_value(v) for v in load) if load else None),
    ]
    return f'<div class="card"><h3>Machine</h3>{definition_list(items)}</div>'


def settings_html(run: RunResult) -> str:
    backends = []
    for entry in run.backends:
        name, label = entry.name or '?', entry.label
        # an instance (--backend LABEL=NAME): its backend and its own --param values
        made_of = [entry.backend] if entry.backend and entry.backend != name else []
        made_of += [f'{key}={value}' for key, value in entry.params.items()]
        if made_of:
            backends.append(f'{label or name} ({" ".join(made_of)})')
        else:
            backends.append(f'{label} ({name})' if label and label != name else name)
    items: list[tuple[str, Any]] = [('backends', ', '.join(backends) or None)]
    items += list(to_json(run.settings).items())
    return f'<div class="card"><h3>Settings</h3>{definition_list(items)}</div>'


# --------------------------------------------------------------------------- summary
