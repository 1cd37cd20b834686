"""Each task declares the recorded outputs the ``recorded`` backend reads of it; the engine's
table of readers is gathered from the registry, and the shared modules that read recorded
outputs decide nothing by a task's name or an output's type."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from replaybench.decode.recorded import OutputReader
from replaybench.errors import TaskUnavailableError
from replaybench.replay import recorded
from replaybench.tasks import LazyMapping, get_task, task_names

REPO = Path(__file__).resolve().parents[2]
#: the shared modules the recorded readers moved out of
SHARED = (
    'replaybench/decode/recorded.py',
    'replaybench/replay/recorded.py',
    'replaybench/backends/recorded.py',
)
#: output types of the tasks, which shared code must not test a result against
TASK_TYPES = {'TagResult', 'TagDetection', 'LabelMask'}


def test_every_registered_task_declares_its_recorded_readers_and_each_reads_for_its_task():
    expected = {
        'detections': {'vision_msgs/msg/Detection2DArray'},
        'tags': {'isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray'},
        'segmentation': {'sensor_msgs/msg/Image'},
        'stereo': {'stereo_msgs/msg/DisparityImage'},
        'tracks': set(),
    }
    for name in task_names():
        readers = get_task(name).recorded_readers
        assert set(readers) == expected[name]
        for reader in readers.values():
            assert isinstance(reader, OutputReader)
            assert reader.task == name
            assert callable(reader.read)


def test_the_engine_table_of_readers_is_the_union_of_the_tasks_in_registry_order():
    gathered = recorded.task_readers()
    assert list(gathered) == [
        msgtype for name in task_names() for msgtype in get_task(name).recorded_readers
    ]
    assert dict(recorded.RECORDED_READERS) == gathered
    assert (
        recorded.output_reader('vision_msgs/Detection2DArray')
        is gathered['vision_msgs/msg/Detection2DArray']
    )


def test_what_a_reader_declares_replaces_the_checks_of_a_task_name():
    readers = recorded.task_readers()
    masks = readers['sensor_msgs/msg/Image']
    boxes = readers['vision_msgs/msg/Detection2DArray']
    tags = readers['isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray']
    assert boxes.unusable == 'detection(s) with a NaN or infinite box or score'
    assert tags.unusable == 'tag(s) with a NaN or infinite corner'
    assert [r.producer for r in (boxes, tags, masks)] == [
        'the detector',
        'the tag detector',
        'the segmentation node',
    ]


def test_two_tasks_reading_one_message_type_is_a_clear_error(monkeypatch):
    from replaybench.tasks.tags.task import TagsTask

    monkeypatch.setattr(
        TagsTask,
        'recorded_readers',
        {
            'vision_msgs/msg/Detection2DArray': get_task('tags').recorded_readers[
                'isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray'
            ]
        },
    )
    with pytest.raises(
        TaskUnavailableError,
        match=r"^task 'tags': recorded message type vision_msgs/msg/Detection2DArray is read by "
        r"task 'detections' already$",
    ):
        recorded.task_readers()


def test_a_lazy_mapping_imports_its_module_only_when_read():
    code = (
        'import sys\n'
        'from replaybench.tasks import get_task\n'
        'readers = get_task("tags").recorded_readers\n'
        'print("replaybench.tasks.tags.recorded" in sys.modules)\n'
        'print(sorted(readers))\n'
        'print("replaybench.tasks.tags.recorded" in sys.modules)\n'
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
    assert done.stdout.splitlines() == [
        'False',
        "['isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray']",
        'True',
    ]
    assert repr(get_task('tags').recorded_readers) == (
        "LazyMapping('replaybench.tasks.tags.recorded:READERS')"
    )
    assert isinstance(get_task('tags').recorded_readers, LazyMapping)


def _branch(node: ast.AST, names: set[str]) -> str:
    """What makes ``node`` a per-task branch ('' when nothing does)."""
    if isinstance(node, ast.Compare):
        sides = [node.left, *node.comparators]
        named = [s.value for s in sides if isinstance(s, ast.Constant) and s.value in names]
        return f'compares with {named[0]!r}' if named else ''
    if isinstance(node, ast.Dict):
        keys = [k.value for k in node.keys if isinstance(k, ast.Constant) and k.value in names]
        return f'a table keyed by {", ".join(map(repr, keys))}' if len(keys) > 1 else ''
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id in {'isinstance', 'issubclass'}
        and len(node.args) == 2
    ):
        kinds = [k.id for k in ast.walk(node.args[1]) if isinstance(k, ast.Name)]
        typed = [k for k in kinds if k in TASK_TYPES]
        return f'a type check for {typed[0]}' if typed else ''
    if isinstance(node, ast.ImportFrom) and node.module is not None:
        fiducials = node.module.startswith('replaybench.fiducials')
        if fiducials or any(alias.name in TASK_TYPES for alias in node.names):
            return f'imports {node.module}'
    return ''


def _task_branches(path: Path) -> list[str]:
    """Comparisons with a task's name, tables keyed by task names, ``isinstance`` with a task's
    output type and imports of a task's types, in a module's code (not its docstrings)."""
    names = set(task_names())
    tree = ast.parse(path.read_text(encoding='utf-8'))
    found = [
        (node.lineno, _branch(node, names)) for node in ast.walk(tree) if hasattr(node, 'lineno')
    ]
    return [f'{path.name}:{line}: {what}' for line, what in sorted(found) if what]


@pytest.mark.parametrize('module', SHARED)
def test_the_shared_modules_that_read_recorded_outputs_hold_no_per_task_branch(module):
    assert _task_branches(REPO / module) == []


def test_the_check_for_per_task_branches_finds_one(tmp_path):
    sample = tmp_path / 'sample.py'
    sample.write_text(
        'from replaybench.fiducials.types import TagResult\n'
        "PRODUCERS = {'tags': 'the tag detector', 'segmentation': 'the node'}\n"
        'def f(reader, result):\n'
        "    if reader.task == 'segmentation':\n"
        '        return isinstance(result, TagResult)\n',
        encoding='utf-8',
    )
    assert _task_branches(sample) == [
        'sample.py:1: imports replaybench.fiducials.types',
        "sample.py:2: a table keyed by 'tags', 'segmentation'",
        "sample.py:4: compares with 'segmentation'",
        'sample.py:5: a type check for TagResult',
    ]
