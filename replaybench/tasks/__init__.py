"""Task registry: the built-in task types plus third-party ones found through entry points.

Built-in tasks are named by ``'module:attr'`` strings and imported only when asked for, so that
nothing of a task is imported before it is needed. Third-party packages register a task object
in the ``replaybench.tasks`` entry-point group; the entry point's name is the task's name.
Each task holds its metric specs (``MetricSpec``); ``all_metrics`` gives them with the metrics
of every task (``COMMON_METRICS``), which compare, its gate, the sweep and the terminal read.
A task's views (``TaskViews``: its report panels, its columns and lines on the terminal) are
``'module:attr'`` strings too, imported by ``load_view`` when the report or the terminal shows
them.
Each task also declares the recorded outputs the ``recorded`` backend reads of it
(``Task.recorded_readers``; ``replaybench.replay.recorded.RECORDED_READERS`` gathers them), and
a task scored against ground truth how its truth is found and read (``TaskTruth``;
``truth_readers`` gives them to the engine, ``replaybench.replay.inputs``). A task may name its
part of recording a processed frame (``task_recording``), which the engine loads once per run
for the backends that declare the task (``Backend.task``; ``require_task`` checks a declared
name without importing a built-in task).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from replaybench._entrypoints import PLUGIN_NAME, declares, sorted_entry_points
from replaybench.errors import TaskUnavailableError, UsageError
from replaybench.tasks.base import (
    LazyMapping,
    MetricSpec,
    Task,
    TaskRecording,
    TaskRecordingBase,
    TaskTruth,
    TaskViews,
    TruthInput,
)
from replaybench.tasks.common import COMMON_METRICS

if TYPE_CHECKING:
    from collections.abc import Collection, Sequence
    from importlib.metadata import EntryPoint
    from pathlib import Path

__all__ = [
    'COMMON_METRICS',
    'ENTRY_POINT_GROUP',
    'TASKS',
    'LazyMapping',
    'MetricSpec',
    'Task',
    'TaskRecording',
    'TaskRecordingBase',
    'TaskTruth',
    'TaskViews',
    'TruthInput',
    'all_metrics',
    'backend_options',
    'frame_columns',
    'get_task',
    'load_view',
    'require_task',
    'streaming_offline',
    'task_names',
    'task_recording',
    'task_truth',
    'task_views',
    'truth_readers',
]

ENTRY_POINT_GROUP = 'replaybench.tasks'

#: Built-in tasks, name -> ``'module:attr'``; imported on first use.
TASKS: dict[str, str] = {
    'detections': 'replaybench.tasks.detections.task:TASK',
    'tags': 'replaybench.tasks.tags.task:TASK',
    'segmentation': 'replaybench.tasks.segmentation.task:TASK',
    'stereo': 'replaybench.tasks.stereo.task:TASK',
    'tracks': 'replaybench.tasks.tracks.task:TASK',
}


def _entry_points() -> list[EntryPoint]:
    """Entry points of the task group, in a stable order (name, then target); none without
    ``importlib.metadata`` loaded where no installed distribution declares the group."""
    if not declares(ENTRY_POINT_GROUP):
        return []
    return sorted_entry_points(ENTRY_POINT_GROUP)


def _plugins() -> tuple[dict[str, EntryPoint], dict[str, str]]:
    """Usable third-party entry points by name, and why the others are refused (by name)."""
    usable: dict[str, EntryPoint] = {}
    refused: dict[str, str] = {}
    for ep in _entry_points():
        if ep.name in TASKS:
            refused[ep.name] = f'{ep.value}: name {ep.name!r} is taken by a built-in task'
        elif not PLUGIN_NAME.match(ep.name):
            refused[ep.name] = f'{ep.value}: invalid task name {ep.name!r} (letters, digits, _, -)'
        elif ep.name in usable:
            refused[ep.name] = (
                f'{ep.value}: name {ep.name!r} is already registered by {usable[ep.name].value}'
            )
        else:
            usable[ep.name] = ep
    return usable, refused


def task_names() -> list[str]:
    """Names of every usable task: built-ins first (registry order), then third-party sorted."""
    return [*TASKS, *sorted(_plugins()[0])]


def _check(name: str, obj: object, target: str) -> Task:
    if not isinstance(obj, Task):
        needs = 'a name, metrics and recorded_readers'
        msg = f'task {name!r}: {target} is not a task (it needs {needs})'
        raise TaskUnavailableError(msg)
    if obj.name != name:
        msg = f'task {name!r}: {target} declares name {obj.name!r}; it must equal {name!r}'
        raise TaskUnavailableError(msg)
    metrics = obj.metrics
    if not isinstance(metrics, tuple) or not all(isinstance(m, MetricSpec) for m in metrics):
        msg = f'task {name!r}: {target}: metrics must be a tuple of MetricSpec'
        raise TaskUnavailableError(msg)
    if not isinstance(obj.recorded_readers, Mapping):
        msg = f'task {name!r}: {target}: recorded_readers must be a mapping (empty for none)'
        raise TaskUnavailableError(msg)
    return obj


def get_task(name: str) -> Task:
    """The task registered as ``name``.

    Raises ``UsageError`` naming the known tasks when ``name`` is unknown, and
    ``TaskUnavailableError`` when its module or entry point cannot be loaded or holds no task.
    """
    if name in TASKS:
        target = TASKS[name]
        module_name, _, attr = target.partition(':')
        try:
            obj = getattr(importlib.import_module(module_name), attr)
        except Exception as exc:  # any import failure makes the task unavailable
            msg = f'task {name!r}: cannot import {target}: {type(exc).__name__}: {exc}'
            raise TaskUnavailableError(msg) from exc
        return _check(name, obj, target)
    usable, refused = _plugins()
    if name in usable:
        ep = usable[name]
        try:
            obj = ep.load()
        except Exception as exc:  # a broken plugin is reported, never imported half
            msg = f'task {name!r}: cannot load {ep.value}: {type(exc).__name__}: {exc}'
            raise TaskUnavailableError(msg) from exc
        return _check(name, obj, ep.value)
    if name in refused:
        msg = f'task {name!r}: entry point {refused[name]}'
        raise TaskUnavailableError(msg)
    msg = f'unknown task {name!r}; known tasks: {", ".join([*TASKS, *sorted(usable)])}'
    raise UsageError(msg)


def require_task(name: str) -> None:
    """Nothing when ``name`` is a registered task (a built-in one is not imported); the
    errors of ``get_task`` otherwise: ``UsageError`` naming the known tasks for an unknown
    name, ``TaskUnavailableError`` for a third-party task that cannot be loaded."""
    if name not in TASKS:
        get_task(name)


def all_metrics() -> tuple[MetricSpec, ...]:
    """``COMMON_METRICS``, then each task's metrics in ``task_names`` order, then each task's
    streaming metrics (``Task.streaming_metrics``, ``replaybench.replay.streaming``).

    ``TaskUnavailableError`` when a task cannot be loaded or a metric name (or alias) is
    declared twice.
    """
    declared: list[tuple[str, MetricSpec]] = [('the common metrics', m) for m in COMMON_METRICS]
    streaming: list[tuple[str, MetricSpec]] = []
    for name in task_names():
        task = get_task(name)
        later = set(getattr(task, 'streaming_metrics', ()))
        declared += [(f'task {name!r}', m) for m in task.metrics if m.name not in later]
        streaming += [(f'task {name!r}', m) for m in task.metrics if m.name in later]
    # every task's streaming metrics (``Task.streaming_metrics``) after the other metrics: the
    # columns of comparison.csv and sweep.csv that were there before them keep their places
    declared += streaming
    owner: dict[str, str] = {}
    for where, spec in declared:
        for known in (spec.name, *spec.aliases):
            if known in owner:
                msg = f'metric {known!r} of {where} is declared by {owner[known]} already'
                raise TaskUnavailableError(msg)
            owner[known] = where
    return tuple(spec for _, spec in declared)


_NO_VIEWS = TaskViews()


def streaming_offline() -> dict[str, tuple[str, str]]:
    """Every task's streaming metrics (``Task.streaming_metrics``, in ``task_names`` order):
    name -> (its label, the name of the offline figure it is the streaming form of)."""
    found: dict[str, tuple[str, str]] = {}
    for name in task_names():
        task = get_task(name)
        labels = {m.name: m.label for m in task.metrics}
        pairs: Mapping[str, str] = getattr(task, 'streaming_metrics', {})
        for streaming, offline in pairs.items():
            found[streaming] = (labels.get(streaming, streaming), str(offline))
    return found


def task_views(task: Task) -> TaskViews:
    """``task``'s views; none (``TaskViews()``) for a task without a ``views`` attribute.

    ``TaskUnavailableError`` when ``views`` is there but no ``TaskViews``, or names a terminal
    metric that is not one of the task's metrics with a ``terminal_label``.
    """
    views = getattr(task, 'views', _NO_VIEWS)
    if not isinstance(views, TaskViews):
        msg = f'task {task.name!r}: views must be a TaskViews, not {type(views).__name__}'
        raise TaskUnavailableError(msg)
    labelled = {m.name for m in task.metrics if m.terminal_label is not None}
    for name in views.terminal_metrics:
        if name not in labelled:
            msg = f'task {task.name!r}: terminal metric {name!r} is no metric of it with a label'
            raise TaskUnavailableError(msg)
    return views


def task_recording(task: Task) -> str | None:
    """The ``'module:attr'`` of ``task``'s part of recording a processed frame (a callable
    ``(recorder) -> TaskRecording``, ``replaybench.replay.recording``); None for a task
    without a ``recording`` attribute, whose frames are recorded as boxes only.

    ``TaskUnavailableError`` when ``recording`` is there but no ``'module:attr'`` string.
    """
    target = getattr(task, 'recording', None)
    if target is not None and (not isinstance(target, str) or ':' not in target):
        msg = f"task {task.name!r}: recording must be a 'module:attr' string, not {target!r}"
        raise TaskUnavailableError(msg)
    return target


def load_view(task: Task, target: str, what: str = 'view') -> Any:
    """The object a view's (or the task's ``what``'s) ``'module:attr'`` string names,
    imported now.

    ``TaskUnavailableError`` naming the task and the target when it cannot be imported.
    """
    module_name, _, attr = target.partition(':')
    try:
        return getattr(importlib.import_module(module_name), attr)
    except Exception as exc:  # any import failure makes the view unavailable
        msg = f'task {task.name!r}: cannot import {what} {target}: {type(exc).__name__}: {exc}'
        raise TaskUnavailableError(msg) from exc


_TRUTH_METHODS = ('truth_topics', 'load_truth', 'open_truth')


def task_truth(task: Task) -> TaskTruth | None:
    """``task``'s ground-truth reader (the task itself), None for a task without truth (none of
    ``truth_topics``, ``load_truth``, ``open_truth``).

    ``TaskUnavailableError`` naming what is missing for a task that has some of them only.
    """
    has = [name for name in _TRUTH_METHODS if callable(getattr(task, name, None))]
    if not has:
        return None
    if not isinstance(task, TaskTruth):
        missing = ', '.join(name for name in _TRUTH_METHODS if name not in has)
        msg = f'task {task.name!r}: it reads ground truth ({", ".join(has)}) but has no {missing}'
        raise TaskUnavailableError(msg)
    return task


def truth_readers() -> list[tuple[str, TaskTruth]]:
    """Every registered task that reads ground truth, by name, in ``task_names`` order."""
    found: list[tuple[str, TaskTruth]] = []
    for name in task_names():
        reader = task_truth(get_task(name))
        if reader is not None:
            found.append((name, reader))
    return found


def backend_options(options: Any, inputs: Sequence[Path]) -> Any:
    """The run's backend options (``replaybench.backends.BackendOptions``) with what each
    registered task reads of the inputs for its backends before they open (a task's
    ``backend_options(options, inputs) -> options``, in ``task_names`` order; the tags task:
    the tag sizes the bags record). Tasks without one leave them as they are."""
    for name in task_names():
        adjust = getattr(get_task(name), 'backend_options', None)
        if adjust is not None:
            options = adjust(options, inputs)
    return options


def frame_columns(tasks: Collection[str]) -> tuple[str, ...]:
    """The frames.csv columns of ``tasks`` (task names), each task's ``frame_columns`` (the
    names its recording's ``frame`` returns that are no ``FrameRecord`` fields; none for a task
    without them, the built-in ones), in ``task_names`` order. ``TaskUnavailableError`` when
    ``frame_columns`` is no tuple of names, or two tasks declare the same name."""
    found: list[str] = []
    for name in task_names():
        if name not in tasks:
            continue
        task = get_task(name)
        columns = getattr(task, 'frame_columns', ())
        if not isinstance(columns, tuple) or not all(isinstance(c, str) and c for c in columns):
            msg = f'task {name!r}: frame_columns must be a tuple of column names'
            raise TaskUnavailableError(msg)
        for column in columns:
            if column in found:
                msg = f'task {name!r}: frame column {column!r} is declared by another task'
                raise TaskUnavailableError(msg)
            found.append(column)
    return tuple(found)
