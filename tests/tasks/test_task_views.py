"""A task's views (report panels, Summary columns, the run table's columns and lines) are
'module:attr' strings imported when shown; a task from the entry-point group adds its own to
report.html and to the terminal without an edit to the report or the CLI."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import pytest

import replaybench as rb
from replaybench.cli.run import _task_columns, _task_lines
from replaybench.errors import TaskUnavailableError
from replaybench.report import render_html
from replaybench.report.taskviews import report_parts
from replaybench.results.folder import load_run
from replaybench.tasks import ENTRY_POINT_GROUP, TaskViews, get_task, load_view, task_views

if TYPE_CHECKING:
    from collections.abc import Iterator

BAG = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'rgb8_raw.mcap'

PLUGIN = """
from replaybench.tasks import MetricSpec, TaskViews

SCORE = MetricSpec('toy_score', 'toy score', 'toy', 'higher', main=True, terminal_label='toy')


def section(rows):
    return '<h2 id="toy">Toy section</h2><p>' + ' '.join(r.backend for r in rows) + '</p>'


def columns(rows):
    return ('toy col',), [('t:' + r.backend,) for r in rows]


def lines(run):
    return [f'toy: {len(run.summary_rows)} row(s)']


class ToyTask:
    name = 'toy'
    metrics = (SCORE,)
    recorded_readers: dict[str, object] = {}
    views = TaskViews(
        summary_field='toy_summary',
        section_panel=f'{__name__}:section',
        more_columns=f'{__name__}:columns',
        terminal_lines=f'{__name__}:lines',
        terminal_metrics=('toy_score',),
    )


class BadViews:
    name = 'badviews'
    metrics = ()
    recorded_readers: dict[str, object] = {}
    views = {'section_panel': 'x:y'}


class UnknownColumn:
    name = 'unknowncolumn'
    metrics = (MetricSpec('plain', 'plain', 'plain', 'higher'),)
    recorded_readers: dict[str, object] = {}
    views = TaskViews(terminal_metrics=('plain',))


class Missing:
    name = 'missing'
    metrics = ()
    recorded_readers: dict[str, object] = {}
    views = TaskViews(section_panel='rb_no_such_module_here:panel')


TASK = ToyTask()
BAD_VIEWS = BadViews()
UNKNOWN_COLUMN = UnknownColumn()
MISSING = Missing()
"""


class Register:
    """Registers tasks of the plugin module through an installed distribution's entry points."""

    def __init__(self, tmp_path: Path, module: str) -> None:
        self.tmp_path, self.module = tmp_path, module

    def __call__(self, **targets: str) -> None:
        dist = self.tmp_path / 'rb_view_tasks-0.1.dist-info'
        dist.mkdir()
        (dist / 'METADATA').write_text(
            'Metadata-Version: 2.1\nName: rb-view-tasks\nVersion: 0.1\n', encoding='utf-8'
        )
        lines = '\n'.join(f'{task} = {self.module}:{attr}' for task, attr in targets.items())
        (dist / 'entry_points.txt').write_text(
            f'[{ENTRY_POINT_GROUP}]\n{lines}\n', encoding='utf-8'
        )


@pytest.fixture
def register(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Register]:
    """A real module of task objects on sys.path, and a way to register some of them."""
    name = f'rb_view_task_{tmp_path.name.replace("-", "_")}'
    (tmp_path / f'{name}.py').write_text(PLUGIN, encoding='utf-8')
    monkeypatch.syspath_prepend(str(tmp_path))
    yield Register(tmp_path, name)
    sys.modules.pop(name, None)


@pytest.fixture(scope='module')
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real run folder: hsv against the bag's box truth, five frames."""
    out = tmp_path_factory.mktemp('views') / 'run'
    rb.run(BAG, backends=['hsv'], out=out, max_frames=5, warmup=0, report=False)
    return out


def test_the_built_in_views_are_imported_when_the_report_loads_them_not_with_the_task() -> None:
    child = textwrap.dedent("""
        import json, sys
        from replaybench.tasks import get_task
        panels = ['replaybench.report.detections', 'replaybench.report.tags']
        for name in ('detections', 'tags', 'segmentation'):
            get_task(name)
        before = [m for m in panels if m in sys.modules]
        from replaybench.report.taskviews import report_parts
        parts = report_parts()
        after = [m for m in panels if m in sys.modules]
        print(json.dumps([before, after, [m.name for m in parts.main]]))
        """)
    found = subprocess.run(
        [sys.executable, '-c', child], capture_output=True, text=True, check=True
    ).stdout
    before, after, main = json.loads(found)
    assert before == []
    assert after == ['replaybench.report.detections', 'replaybench.report.tags']
    # each task's main figure, in task order
    assert main == ['map50', 'tag_recall', 'miou', 'bad2', 'hota']


def test_the_run_table_takes_the_boxes_columns_for_every_row_and_masks_only_where_scored(
    run_dir: Path,
) -> None:
    rows = list(load_run(run_dir).run.summary_rows)
    always, scored = _task_columns(rows)
    assert [m.name for m in always] == ['precision50', 'recall50', 'map50']
    assert scored == []  # no row has a segmentation summary


def test_a_task_from_an_entry_point_adds_its_section_and_columns_to_the_report(
    register: Register, run_dir: Path
) -> None:
    register(toy='TASK')
    html = render_html(load_run(run_dir))
    assert '<h2 id="toy">Toy section</h2><p>hsv</p>' in html
    assert '<th class="n">toy col</th>' in html
    assert '<td class="n">t:hsv</td>' in html
    # its main figure is no field of the run's rows: no column for it
    assert '<th class="n">toy</th>' not in html


def test_a_task_from_an_entry_point_prints_its_lines_after_the_run_table(
    register: Register, run_dir: Path
) -> None:
    register(toy='TASK')
    run = load_run(run_dir).run
    assert _task_lines(run) == ['toy: 1 row(s)']
    _, scored = _task_columns(list(run.summary_rows))
    assert scored == []  # the rows have no toy summary


def test_the_report_without_the_plugin_has_none_of_its_parts(run_dir: Path) -> None:
    html = render_html(load_run(run_dir))
    assert 'Toy section' not in html
    assert 'toy col' not in html


def test_views_that_are_no_task_views_make_the_task_unavailable(register: Register) -> None:
    register(badviews='BAD_VIEWS')
    with pytest.raises(TaskUnavailableError, match="task 'badviews': views must be a TaskViews"):
        task_views(get_task('badviews'))


def test_a_terminal_metric_without_a_terminal_label_makes_the_task_unavailable(
    register: Register,
) -> None:
    register(unknowncolumn='UNKNOWN_COLUMN')
    with pytest.raises(TaskUnavailableError, match="terminal metric 'plain' is no metric"):
        task_views(get_task('unknowncolumn'))


def test_a_view_that_cannot_be_imported_is_one_line_naming_the_task_and_the_target(
    register: Register,
) -> None:
    register(missing='MISSING')
    task = get_task('missing')
    target = task_views(task).section_panel
    assert target is not None
    with pytest.raises(TaskUnavailableError) as raised:
        load_view(task, target)
    message = str(raised.value)
    assert '\n' not in message
    assert message.startswith("task 'missing': cannot import view rb_no_such_module_here:panel")
    with pytest.raises(TaskUnavailableError):
        report_parts()


def test_a_task_without_views_has_none() -> None:
    class Plain:
        name = 'plain'
        metrics = ()
        recorded_readers: ClassVar[dict[str, Any]] = {}

    assert task_views(Plain()) == TaskViews()
