"""The engine records a frame as the task its backend declares: each task names its part of
recording (``task_recording``), loaded once per run; the engine and the sinks test no result's
type, no writer's type or attributes and no task's name to find out what a frame is."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path
from typing import ClassVar, cast

import pytest

from replaybench.errors import TaskUnavailableError, UsageError
from replaybench.replay.output import Discard
from replaybench.tasks import get_task, require_task, task_names, task_recording

REPO = Path(__file__).resolve().parents[2]
#: the modules that record a frame, write its outputs or drive the passes
ENGINE = sorted(
    [
        *(REPO / 'replaybench' / 'replay').glob('*.py'),
        *(REPO / 'replaybench' / 'sinks').glob('*.py'),
    ]
)
#: those that decide, per pass or per frame, what a backend's result leads to
DISPATCH = ('recording.py', 'passes.py', 'sessions.py')
#: the tasks' output types and the writers, which shared code must not test a value against
TYPES = {'TagResult', 'TagDetection', 'LabelMask', 'DetectionsWriter', 'Discard'}
#: attributes whose presence told the writers (or the results) apart
ATTRIBUTES = {'add_message', 'add_metadata', 'mask', 'tags', 'task'}


def test_each_built_in_task_names_its_part_of_recording_a_frame():
    assert {name: task_recording(get_task(name)) for name in task_names()} == {
        'detections': None,  # boxes only: the part every task has
        'tags': 'replaybench.tasks.tags.recording:recording',
        'segmentation': 'replaybench.tasks.segmentation.recording:recording',
        'stereo': 'replaybench.tasks.stereo.recording:recording',
        'tracks': 'replaybench.tasks.tracks.recording:recording',
    }


def test_a_recording_that_is_no_module_attr_string_is_refused_naming_the_task():
    class Odd:
        name = 'odd'
        metrics = ()
        recorded_readers: ClassVar[dict[str, object]] = {}
        recording = 42

    with pytest.raises(TaskUnavailableError, match=r"^task 'odd': recording must be a "):
        task_recording(Odd())  # type: ignore[arg-type]


def test_a_declared_task_is_checked_without_importing_a_built_in_one():
    code = (
        'import sys\n'
        'from replaybench.tasks import require_task\n'
        'for name in ("detections", "tags", "segmentation"):\n'
        '    require_task(name)\n'
        'print(sorted(m for m in sys.modules if m.startswith("replaybench.tasks.")))\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', code],
        capture_output=True,
        text=True,
        check=True,
        cwd=REPO,
        env={'PYTHONPATH': str(REPO)},
        timeout=60,
    )
    assert done.stdout.strip() == "['replaybench.tasks.base', 'replaybench.tasks.common']"
    with pytest.raises(UsageError, match=r"^unknown task 'flow'; known tasks: detections, "):
        require_task('flow')


def _dispatch(node: ast.AST, names: set[str], dispatching: bool) -> str:
    """What makes ``node`` a task dispatch ('' when nothing does)."""
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        if node.func.id in {'isinstance', 'issubclass'} and len(node.args) == 2:
            kinds = [k.id for k in ast.walk(node.args[1]) if isinstance(k, ast.Name)]
            typed = [k for k in kinds if k in TYPES]
            return f'a type check for {typed[0]}' if typed else ''
        if node.func.id in {'hasattr', 'getattr'} and len(node.args) >= 2:
            attr = node.args[1]
            if isinstance(attr, ast.Constant) and attr.value in ATTRIBUTES:
                return f'{node.func.id} {attr.value!r}'
    if dispatching and isinstance(node, ast.Compare):
        sides = [node.left, *node.comparators]
        named = [s.value for s in sides if isinstance(s, ast.Constant) and s.value in names]
        if named:
            return f'compares with {named[0]!r}'
        read = [
            s.attr if isinstance(s, ast.Attribute) else s.id
            for s in sides
            if (isinstance(s, ast.Attribute) and s.attr in ATTRIBUTES)
            or (isinstance(s, ast.Name) and s.id in ATTRIBUTES)
        ]
        if read:
            return f'compares .{read[0]}'
    return ''


def _dispatches(path: Path) -> list[str]:
    names = set(task_names())
    tree = ast.parse(path.read_text(encoding='utf-8'))
    dispatching = path.name in DISPATCH
    found = [
        (node.lineno, _dispatch(node, names, dispatching))
        for node in ast.walk(tree)
        if hasattr(node, 'lineno')
    ]
    return [f'{path.name}:{line}: {what}' for line, what in sorted(found) if what]


@pytest.mark.parametrize('module', ENGINE, ids=lambda p: f'{p.parent.name}/{p.name}')
def test_the_engine_and_the_sinks_hold_no_type_or_attribute_dispatch_of_a_task(module):
    assert _dispatches(module) == []


def test_the_check_for_a_task_dispatch_finds_one(tmp_path):
    sample = tmp_path / 'recording.py'
    sample.write_text(
        'def f(writer, result, task):\n'
        '    mask = result.mask\n'
        '    if isinstance(result, TagResult) and hasattr(writer, "add_message"):\n'
        '        return result.mask is None or mask is not None\n'
        "    return task == 'segmentation' or isinstance(writer, DetectionsWriter)\n",
        encoding='utf-8',
    )
    assert _dispatches(sample) == [
        'recording.py:3: a type check for TagResult',
        "recording.py:3: hasattr 'add_message'",
        'recording.py:4: compares .mask',
        'recording.py:4: compares .mask',
        'recording.py:5: a type check for DetectionsWriter',
        "recording.py:5: compares with 'segmentation'",
    ]


def test_the_built_in_recordings_are_made_once_per_run_by_the_recorder_from_the_task_folders():
    from replaybench.replay.passes import Warmups
    from replaybench.replay.recording import Recorder, TaskRecording
    from replaybench.tasks.segmentation.recording import Segmentation
    from replaybench.tasks.tags.recording import TagScores

    recorder = Recorder([], Warmups(0, {}), Discard(), Discard(), backends=2)
    made: list[TaskRecording | None] = [
        recorder.task_recording('tags'),
        recorder.task_recording('segmentation'),
    ]
    assert [type(r) for r in made] == [TagScores, Segmentation]
    assert made[0] is recorder.task_recording('tags')  # the same objects, made once
    assert recorder.task_recordings() == made
    assert [(r.scores_boxes, r.writes_first) for r in made if r is not None] == [
        (True, False),
        (False, True),
    ]
    assert cast('Segmentation', made[1]).keep  # two backends: masks kept for their agreement
    alone = Recorder([], Warmups(0, {}), Discard(), Discard()).task_recording('segmentation')
    assert not cast('Segmentation', alone).keep
    assert recorder.task_recording('detections') is None
