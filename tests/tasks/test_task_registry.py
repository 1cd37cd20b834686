"""Task registry: built-in tasks resolved on use, third-party tasks through the entry-point
group, clear errors, and every metric compare and the sweep know coming from a task's spec."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import textwrap
from typing import TYPE_CHECKING

import pytest

from replaybench.app.sweep.record import CSV_COLUMNS as SWEEP_CSV_COLUMNS
from replaybench.app.sweep.record import SWEEP_METRICS
from replaybench.comparison import ACCURACY_METRICS, METRICS, RECORDED_METRICS, TIMING_METRICS
from replaybench.comparison.core import RIG_METRICS, TAG_METRICS
from replaybench.comparison.output import CSV_COLUMNS as COMPARISON_CSV_COLUMNS
from replaybench.errors import TaskUnavailableError, UsageError
from replaybench.results.columns import TAG_SUMMARY_COLUMNS
from replaybench.results.model import SummaryRow
from replaybench.results.sweepfile import CellMetrics
from replaybench.tasks import (
    COMMON_METRICS,
    ENTRY_POINT_GROUP,
    TASKS,
    MetricSpec,
    Task,
    all_metrics,
    get_task,
    task_names,
)

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

PLUGIN = """
from replaybench.tasks import MetricSpec


class ToyTask:
    name = 'toy'
    metrics = (MetricSpec('toy_score', 'toy score', 'score', 'higher', sweep=True),)
    recorded_readers = {}


class Misnamed:
    name = 'something-else'
    metrics = ()
    recorded_readers = {}


class Clashing:
    name = 'clash'
    metrics = (MetricSpec('map50', 'mAP again', 'mAP', 'higher'),)
    recorded_readers = {}


TASK = ToyTask()
MISNAMED = Misnamed()
CLASHING = Clashing()
NOT_A_TASK = 42
"""


@pytest.fixture
def plugin_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A real importable module holding third-party task objects."""
    name = f'rb_toy_task_{tmp_path.name.replace("-", "_")}'
    (tmp_path / f'{name}.py').write_text(PLUGIN, encoding='utf-8')
    monkeypatch.syspath_prepend(str(tmp_path))
    yield name
    sys.modules.pop(name, None)


def distribution(tmp_path: Path, **targets: str) -> None:
    """An installed distribution (a .dist-info folder on sys.path) declaring task entry points."""
    dist = tmp_path / 'rb_toy_tasks-0.3.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text(
        'Metadata-Version: 2.1\nName: rb-toy-tasks\nVersion: 0.3\n', encoding='utf-8'
    )
    lines = '\n'.join(f'{name} = {target}' for name, target in targets.items())
    (dist / 'entry_points.txt').write_text(f'[{ENTRY_POINT_GROUP}]\n{lines}\n', encoding='utf-8')


def test_built_in_tasks_are_module_strings_resolved_on_first_use() -> None:
    child = textwrap.dedent("""
        import json, sys
        import replaybench.tasks as registry
        watched = [target.partition(':')[0] for target in registry.TASKS.values()]
        before = [m for m in watched if m in sys.modules]
        names = registry.task_names()
        listed = [m for m in watched if m in sys.modules]
        task = registry.get_task('tags')
        after = [m for m in watched if m in sys.modules]
        same = task is sys.modules['replaybench.tasks.tags.task'].TASK
        print(json.dumps([before, names, listed, after, same]))
        """)
    found = subprocess.run(
        [sys.executable, '-c', child], capture_output=True, text=True, check=True
    ).stdout
    before, names, listed, after, same = json.loads(found)
    assert before == []
    assert names[:5] == ['detections', 'tags', 'segmentation', 'stereo', 'tracks']
    assert listed == []  # listing the names imports no task
    assert after == ['replaybench.tasks.tags.task']
    assert same is True


def test_built_in_tasks_are_tasks_named_as_registered() -> None:
    assert list(TASKS) == ['detections', 'tags', 'segmentation', 'stereo', 'tracks']
    for name in TASKS:
        task = get_task(name)
        assert isinstance(task, Task)
        assert task.name == name
        assert task.metrics
        assert all(isinstance(m, MetricSpec) for m in task.metrics)


def test_an_unknown_task_is_a_usage_error_listing_the_known_ones() -> None:
    with pytest.raises(
        UsageError,
        match=r"unknown task 'flow'; known tasks: detections, tags, segmentation, stereo, tracks",
    ):
        get_task('flow')


def test_an_installed_distribution_registers_a_task_through_the_entry_point_group(
    tmp_path: Path, plugin_module: str
) -> None:
    distribution(tmp_path, toy=f'{plugin_module}:TASK')
    assert task_names() == ['detections', 'tags', 'segmentation', 'stereo', 'tracks', 'toy']
    task = get_task('toy')
    assert type(task).__module__ == plugin_module
    assert [m.name for m in task.metrics] == ['toy_score']
    names = [m.name for m in all_metrics()]
    # after the built-in tasks' metrics, before every task's streaming metrics
    streaming = [n for n in names if n.startswith('streaming_')]
    assert names[-len(streaming) - 1 :] == ['toy_score', *streaming]
    assert [n for n in names if n != 'toy_score'] == [
        m.name for m in registry_metrics_without_plugins()
    ]


def registry_metrics_without_plugins() -> list[MetricSpec]:
    """The common metrics, the built-in tasks' and then their streaming metrics."""
    specs = [m for name in TASKS for m in get_task(name).metrics]
    streaming = {n for name in TASKS for n in getattr(get_task(name), 'streaming_metrics', ())}
    return [
        *COMMON_METRICS,
        *(m for m in specs if m.name not in streaming),
        *(m for m in specs if m.name in streaming),
    ]


def test_broken_entry_points_are_refused_with_one_line_naming_them(
    tmp_path: Path, plugin_module: str
) -> None:
    distribution(
        tmp_path,
        gone='rb_no_such_module_anywhere:TASK',
        misnamed=f'{plugin_module}:MISNAMED',
        number=f'{plugin_module}:NOT_A_TASK',
        tags=f'{plugin_module}:TASK',
    )
    assert task_names() == [
        'detections',
        'tags',
        'segmentation',
        'stereo',
        'tracks',
        'gone',
        'misnamed',
        'number',
    ]
    with pytest.raises(TaskUnavailableError, match=r"task 'gone': cannot load .*ModuleNotFound"):
        get_task('gone')
    with pytest.raises(TaskUnavailableError, match=r"declares name 'something-else'"):
        get_task('misnamed')
    with pytest.raises(TaskUnavailableError, match=r'NOT_A_TASK is not a task'):
        get_task('number')
    # a name taken by a built-in keeps the built-in
    assert get_task('tags') is sys.modules['replaybench.tasks.tags.task'].TASK
    with pytest.raises(TaskUnavailableError) as failed:
        all_metrics()
    assert '\n' not in str(failed.value)


def test_a_metric_name_declared_by_two_tasks_is_refused(tmp_path: Path, plugin_module: str) -> None:
    distribution(tmp_path, clash=f'{plugin_module}:CLASHING')
    with pytest.raises(
        TaskUnavailableError,
        match=r"metric 'map50' of task 'clash' is declared by task 'detections' already",
    ):
        all_metrics()


def test_metric_names_and_aliases_are_unique() -> None:
    known = [n for m in all_metrics() for n in (m.name, *m.aliases)]
    assert len(known) == len(set(known))


def test_every_metric_compare_knows_comes_from_a_spec_in_table_order() -> None:
    specs = {m.name: m for m in all_metrics()}
    assert set(METRICS) <= set(specs)
    assert all(specs[m].gate for m in METRICS)
    assert TIMING_METRICS == ('median_ms', 'p99_ms', 'mean_ms', 'fps')
    assert all(specs[m].kind == 'timing' for m in TIMING_METRICS)
    assert all(specs[m].kind == 'recorded' for m in RECORDED_METRICS)
    assert all(specs[m].accuracy and not specs[m].appended for m in ACCURACY_METRICS)
    assert all(specs[m].accuracy and specs[m].appended for m in TAG_METRICS)
    assert RIG_METRICS == ('rig_p99_ms', 'rig_drop_rate')
    assert all(specs[m].kind == 'rig' for m in RIG_METRICS)
    assert METRICS == (
        TIMING_METRICS + ACCURACY_METRICS + TAG_METRICS + RECORDED_METRICS + RIG_METRICS
    )
    # comparison.csv: the appended accuracy metrics after ``flags``
    flags = COMPARISON_CSV_COLUMNS.index('flags')
    assert COMPARISON_CSV_COLUMNS.index(f'{ACCURACY_METRICS[-1]}_delta') < flags
    assert COMPARISON_CSV_COLUMNS.index(TAG_METRICS[0]) > flags


def test_the_tag_task_declares_the_summary_csv_tag_columns_in_their_order() -> None:
    streaming = set(get_task('tags').streaming_metrics)  # type: ignore[attr-defined]
    names = tuple(m.name for m in get_task('tags').metrics if m.name not in streaming)
    assert names == TAG_SUMMARY_COLUMNS


def test_every_accuracy_metric_is_a_summary_row_field_or_of_a_task_without_fields() -> None:
    fields = {f.name for f in dataclasses.fields(SummaryRow)}
    # the stereo and tracks tasks keep their metrics in SummaryRow.task_metrics (their
    # frame_columns too)
    own = {m.name for name in ('stereo', 'tracks') for m in get_task(name).metrics}
    assert not own & fields
    assert get_task('stereo').frame_columns  # type: ignore[attr-defined]
    assert get_task('tracks').frame_columns == ('track_ms',)  # type: ignore[attr-defined]
    # every task's streaming metrics (replaybench.replay.streaming) are in task_metrics too
    streaming = {n for t in task_names() for n in getattr(get_task(t), 'streaming_metrics', ())}
    assert streaming
    assert not streaming & fields
    assert {m.name for m in all_metrics() if m.accuracy} - own - streaming <= fields


def test_the_sweep_shows_the_metrics_whose_spec_says_so() -> None:
    shown = {m.name for m in all_metrics() if m.sweep}
    assert set(SWEEP_METRICS) == shown
    assert SWEEP_METRICS == (
        'map50',
        'miou',
        'tag_recall',
        'tag_rot_err_deg',
        'epe',
        'bad2',
        'd1_all',
        'density',
        'hota',
        'assa',
        'idf1',
        'mota',
        'streaming_map50',
    )
    start = SWEEP_CSV_COLUMNS.index('p99_high') + 1
    assert SWEEP_CSV_COLUMNS[start : start + len(SWEEP_METRICS)] == SWEEP_METRICS
    # a cell holds them by name; ``metrics.map50`` still reads one, None where it has none
    held = CellMetrics(values=dict.fromkeys(SWEEP_METRICS, 0.5))
    assert all(getattr(held, name) == 0.5 for name in shown)
    assert all(CellMetrics().value(name) is None for name in shown)
    with pytest.raises(AttributeError, match='no_such_metric'):
        _ = held.no_such_metric


def test_a_spec_writes_values_as_the_gate_does() -> None:
    specs = {m.name: m for m in all_metrics()}
    assert specs['p99_ms'].value_text(12.345678) == '12.35 ms'
    assert specs['fps'].value_text(250.0) == '250 fps'
    assert specs['map50'].value_text(0.5) == '0.5000'
    assert specs['tag_rot_err_deg'].value_text(1.25) == '1.2500'


def test_common_metrics_belong_to_no_task() -> None:
    common = {m.name for m in COMMON_METRICS}
    for name in TASKS:
        assert common.isdisjoint(m.name for m in get_task(name).metrics)
    assert all(not m.accuracy for m in COMMON_METRICS)
