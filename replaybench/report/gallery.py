"""report.html's Samples: the sample pictures of the run folder, embedded."""

from __future__ import annotations

import base64
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING

from replaybench.report.markup import escaped
from replaybench.report.samples import sample_relpath

if TYPE_CHECKING:
    from collections.abc import Callable

    from replaybench.results.model import RunResult

__all__ = ['samples_html']

_MAX_SAMPLE_BYTES = 4 << 20
_IMAGE_TYPES = {'.jpg': 'image/jpeg', '.jpeg': 'image/jpeg', '.png': 'image/png'}


def _captions() -> list[Callable[[str], tuple[str, str] | None]]:
    """Each registered task's ``TaskViews.sample_caption``, in the tasks' order."""
    from replaybench.tasks import get_task, load_view, task_names, task_views

    found = []
    for name in task_names():
        task = get_task(name)
        target = task_views(task).sample_caption
        if target is not None:
            found.append(load_view(task, target))
    return found


def _sample_entries(run: RunResult) -> list[tuple[str, str, str]]:
    """(relative path, topic or '', caption) of each sample listed in run.json: a frame's
    sample under its topic, a task's picture of it (``TaskViews.sample_caption``) beside it."""
    captions = _captions()
    known: dict[str, str] = {}
    for source in run.inputs:
        for meta in source.topics:
            known[sample_relpath(source.index, meta.name)] = meta.name
    result = []
    for rel in run.outputs.samples if run.outputs is not None else ():
        topic = known.get(rel, '')
        caption = topic or PurePosixPath(rel).name
        for named in captions if not topic else ():
            if (found := named(rel)) is not None:  # beside its frame
                topic, caption = known.get(found[0], ''), found[1]
                break
        result.append((rel, topic, caption))
    return result


def _sample_data_uri(run_dir: Path, rel: str) -> str | None:
    pure = PurePosixPath(rel)
    if pure.is_absolute() or '..' in pure.parts or pure.suffix.lower() not in _IMAGE_TYPES:
        return None
    path = run_dir.joinpath(*pure.parts)
    try:
        if not path.resolve().is_relative_to(run_dir.resolve()) or not path.is_file():
            return None
        if path.stat().st_size > _MAX_SAMPLE_BYTES:
            return None
        data = path.read_bytes()
    except OSError:
        return None
    encoded = base64.b64encode(data).decode('ascii')
    return f'data:{_IMAGE_TYPES[pure.suffix.lower()]};base64,{encoded}'


def samples_html(run: RunResult, run_dir: Path) -> str:
    entries = _sample_entries(run)
    if not entries:
        return ''
    groups: dict[str, list[str]] = {}
    for rel, topic, caption in entries:
        uri = _sample_data_uri(run_dir, rel)
        if uri is None:
            figure = (
                f'<figure><figcaption>{escaped(caption)}: <code>{escaped(rel)}</code> is missing '
                'or not an image in the run folder</figcaption></figure>'
            )
        else:
            figure = (
                f'<figure><img src="{uri}" alt="{escaped(caption)}">'
                f'<figcaption>{escaped(caption)}</figcaption></figure>'
            )
        groups.setdefault(topic, []).append(figure)
    parts = ['<h2 id="samples">Samples</h2>']
    for topic, figures in groups.items():
        if topic:
            parts.append(f'<h3><code>{escaped(topic)}</code></h3>')
        parts.append(f'<div class="samples">{"".join(figures)}</div>')
    return ''.join(parts)


# --------------------------------------------------------------------------- details
