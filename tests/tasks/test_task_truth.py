"""Each task finds and reads its own ground truth (``TaskTruth``); the engine opens every
registered task's truth as an input opens, keeps each task's truth topics out of the replayed
cameras, and names no task while doing so."""

from __future__ import annotations

import ast
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from replaybench.errors import TaskUnavailableError
from replaybench.replay.config import InputOptions, RunConfig
from replaybench.replay.inputs import RunTruth, load_truths, open_input
from replaybench.tasks import ENTRY_POINT_GROUP, TaskTruth, get_task, task_names, task_truth
from replaybench.tasks.detections.truth import BoxTruth
from replaybench.tasks.segmentation.truth import MaskTopic

if TYPE_CHECKING:
    from collections.abc import Iterator

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / 'fixtures' / 'bags'

TOY = """
class ToyTruth:
    def __init__(self, topic, source):
        self.topic, self.source = topic, source


class ToyTask:
    name = 'toy'
    metrics = ()
    recorded_readers = {}

    def truth_topics(self, options):
        return frozenset({'/toy/truth'})

    def load_truth(self, config):
        return 'loaded once'

    def open_truth(self, inp, options, loaded, notes):
        if '/toy/truth' not in inp.images:
            return None
        notes.append(f'toy truth of input {inp.number} ({loaded})')
        return ToyTruth('/toy/truth', inp.source)


class HalfTask:
    name = 'half'
    metrics = ()
    recorded_readers = {}

    def truth_topics(self, options):
        return frozenset()


TASK = ToyTask()
HALF = HalfTask()
"""


def _toy_bag(path: Path) -> Path:
    """Three rgb8 frames on a camera topic and three on the toy task's truth topic."""
    from mcap.writer import Writer

    from replaybench.fixtures.writer import stamp_ns
    from replaybench.msgs import IMAGE, ros2msg_schema, serialize_image

    with path.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='ros2', library='tests')
        schema = writer.register_schema(
            name=IMAGE, encoding='ros2msg', data=ros2msg_schema(IMAGE).encode()
        )
        channels = {
            topic: writer.register_channel(topic=topic, message_encoding='cdr', schema_id=schema)
            for topic in ('/cam/image_raw', '/toy/truth')
        }
        image = np.zeros((8, 8, 3), dtype=np.uint8)
        for i in range(3):
            t = stamp_ns(i)
            for channel in channels.values():
                data = serialize_image(t, 'cam', image, 'rgb8')
                writer.add_message(channel_id=channel, log_time=t, data=data, publish_time=t)
        writer.finish()
    return path


@pytest.fixture
def toy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The toy tasks installed: a module and a distribution declaring them as entry points."""
    module = f'rb_truth_task_{tmp_path.name.replace("-", "_")}'
    (tmp_path / f'{module}.py').write_text(TOY, encoding='utf-8')
    dist = tmp_path / 'rb_truth_tasks-0.1.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text(
        'Metadata-Version: 2.1\nName: rb-truth-tasks\nVersion: 0.1\n', encoding='utf-8'
    )
    (dist / 'entry_points.txt').write_text(
        f'[{ENTRY_POINT_GROUP}]\ntoy = {module}:TASK\nhalf = {module}:HALF\n', encoding='utf-8'
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop(module, None)


def test_every_built_in_task_reads_its_own_truth_and_names_its_truth_topics():
    options = InputOptions()
    topics = {}
    for name in ('detections', 'tags', 'segmentation'):
        reader = task_truth(get_task(name))
        assert isinstance(reader, TaskTruth)
        topics[name] = reader.truth_topics(options)
    assert topics == {
        'detections': {'/ground_truth/detections'},
        'tags': {'/ground_truth/tags'},
        'segmentation': {'/ground_truth/labels'},
    }
    masks = task_truth(get_task('segmentation'))
    assert masks is not None
    assert masks.truth_topics(InputOptions(ground_truth_masks=str(BAGS))) == frozenset()


def test_an_input_holds_each_tasks_truth_by_task_name_and_masks_are_read_when_scored():
    bag = BAGS / 'live_masks.mcap'
    config = RunConfig(inputs=[bag], backends=['null'], out_dir=None)
    inp = open_input(0, bag, config.input_options(), load_truths(config))
    try:
        assert set(inp.truth) == {'detections', 'segmentation'}  # no /ground_truth/tags
        boxes = inp.truth['detections']
        assert isinstance(boxes, BoxTruth)
        assert boxes.external is None
        assert len(boxes.frames) > 0
        masks = inp.truth['segmentation']
        assert isinstance(masks, MaskTopic)
        assert masks._index is None  # nothing of the masks read when the input opened
        assert '/ground_truth/labels' not in [t.name for t in inp.topics]
        (frame_id, stamp), *_ = boxes.frames
        found = masks.lookup(frame_id, stamp)
        assert found is not None
        assert found.dtype == np.uint8
        assert found.ndim == 2
    finally:
        inp.source.close()


@pytest.mark.usefixtures('toy')
def test_a_task_from_an_entry_point_has_its_truth_topic_kept_out_of_the_cameras_and_opened(
    tmp_path: Path,
) -> None:
    bag = _toy_bag(tmp_path / 'toy.mcap')
    with pytest.raises(TaskUnavailableError, match=r"task 'half': .* has no load_truth, open"):
        load_truths(RunConfig(inputs=[bag], backends=['null'], out_dir=None))
    assert 'toy' in task_names()
    reader = task_truth(get_task('toy'))
    assert reader is not None
    truths = RunTruth((('toy', reader, reader.load_truth(None)),))
    inp = open_input(0, bag, InputOptions(), truths)
    try:
        assert [t.name for t in inp.topics] == ['/cam/image_raw']
        assert getattr(inp.truth['toy'], 'topic', None) == '/toy/truth'
        assert inp.notes == ('toy truth of input 0 (loaded once)',)
    finally:
        inp.source.close()
    without = open_input(0, bag, InputOptions(), RunTruth())
    try:  # without the task, its truth topic is one more camera
        assert [t.name for t in without.topics] == ['/cam/image_raw', '/toy/truth']
    finally:
        without.source.close()


def test_the_engine_that_opens_inputs_names_no_task_and_none_of_their_truth():
    path = REPO / 'replaybench' / 'replay' / 'inputs.py'
    tree = ast.parse(path.read_text(encoding='utf-8'))
    task_names_used = {'detections', 'tags', 'segmentation', 'masks', 'labels'}
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            words = set(node.value.replace('/', ' ').replace('_', ' ').split())
            code = not (' ' in node.value.strip() or '\n' in node.value)  # a name, not prose
            assert not (code and words & task_names_used), node.value
            assert '/ground_truth/' not in node.value, node.value
        if isinstance(node, ast.ImportFrom):
            assert not (node.module or '').startswith('replaybench.tasks.'), node.module
            assert not (node.module or '').startswith('replaybench.results.groundtruth')
        if isinstance(node, ast.Attribute):
            assert node.attr not in {'ground_truth', 'tag_truth', 'external'}, node.attr
            assert not node.attr.startswith('ground_truth_'), node.attr
