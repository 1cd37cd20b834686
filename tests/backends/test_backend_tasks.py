"""A backend declares the task of its results (``Backend.task``); the runner reads it once the
backend has opened, refuses one that is not registered, and records each frame as its task."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import pytest

from replaybench.backends import BUILTIN_BACKENDS, get_backend
from replaybench.backends.base import (
    BackendOptions,
    RecordedDetections,
    backend_task,
    backend_traits,
)
from replaybench.backends.hsv_seg import HsvSegBackend
from replaybench.backends.null import NullBackend
from replaybench.backends.recorded import RecordedBackend
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.fixtures.writer import write_mcap
from replaybench.replay.recorded import task_readers
from replaybench.replay.runner import RunConfig, run_benchmark

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.types import BackendResult, Frame


def test_each_built_in_backend_declares_the_task_of_its_results():
    declared = {name: backend_traits(get_backend(name)).task for name in BUILTIN_BACKENDS}
    assert {n: t for n, t in declared.items() if t != 'detections'} == {
        'apriltag': 'tags',
        'aruco': 'tags',
        'hsv-seg': 'segmentation',
        'onnx-seg': 'segmentation',
        'sgbm': 'stereo',
        'bm': 'stereo',
        'onnx-stereo': 'stereo',
        'cuda-stereo': 'stereo',
        'tensorrt-stereo': 'stereo',
    }
    # cuda and tensorrt know theirs from the model they open: boxes until then
    assert declared['cuda'] == declared['tensorrt'] == 'detections'


def test_a_backend_that_declares_no_task_is_a_detector():
    class Plain:
        name: ClassVar[str] = 'plain'

    assert backend_traits(Plain).task == 'detections'
    assert backend_task(Plain(), 0) == 'detections'


def test_the_recorded_backend_takes_each_inputs_task_from_its_topics_reader():
    readers = task_readers()
    backend = RecordedBackend()
    backend.prepare(
        RecordedDetections(
            '/recorded',
            {},
            {
                0: readers['isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray'],
                1: readers['sensor_msgs/msg/Image'],
                2: readers['vision_msgs/msg/Detection2DArray'],
            },
        )
    )
    assert [backend_task(backend, i) for i in range(4)] == [
        'tags',
        'segmentation',
        'detections',
        'detections',  # an input without a recorded topic
    ]


@pytest.mark.parametrize('task', [3, '', None])
def test_a_task_that_is_no_name_is_refused_naming_the_backend(task):
    class Odd:
        name: ClassVar[str] = 'odd'

    Odd.task = task  # type: ignore[attr-defined]
    with pytest.raises(BackendUnavailableError, match=r"^backend 'odd' declares task .*"):
        backend_traits(Odd)


class _SegOnceOpen(HsvSegBackend):
    """hsv-seg that, as cuda does, knows it segments only once it has opened."""

    name: ClassVar[str] = 'seg-once-open'
    task: str = 'detections'  # type: ignore[misc]
    learns = True

    def open(self) -> None:
        super().open()
        if self.learns:
            self.task = 'segmentation'


def _mask_bag(tmp_path: Path) -> Path:
    return write_mcap(tmp_path / 'masks.mcap', 4, masks=True)


def _run(bag: Path, backend: Any) -> Any:
    config = RunConfig(inputs=[bag], backends=[backend.name], out_dir=None, warmup=0)
    return run_benchmark(config, backend_factory=lambda name, options: backend)


def test_a_backend_that_learns_its_task_when_it_opens_is_recorded_as_that_task(tmp_path):
    bag = _mask_bag(tmp_path)
    learned = _run(bag, _SegOnceOpen(BackendOptions(threads=1))).run
    (row,) = learned.summary_rows
    assert row.segmentation is not None
    assert row.segmentation.frames == 4
    assert all(r.miou is not None for r in learned.frame_records)

    # the same masks from a backend that stays a detector: recorded as boxes only
    unlearned = _SegOnceOpen(BackendOptions(threads=1))
    unlearned.learns = False
    (plain,) = _run(bag, unlearned).run.summary_rows
    assert plain.segmentation is None


class _Declares(NullBackend):
    name: ClassVar[str] = 'declares'
    task: ClassVar[str] = 'flow'
    detected = 0
    closed = 0

    def detect(self, frame: Frame) -> BackendResult:
        type(self).detected += 1
        return super().detect(frame)

    def close(self) -> None:
        type(self).closed += 1


def test_a_backend_that_declares_an_unknown_task_is_refused_in_one_line_before_any_frame(
    tmp_path,
):
    bag = write_mcap(tmp_path / 'b.mcap', 3)
    with pytest.raises(BackendError) as caught:
        _run(bag, _Declares(BackendOptions()))
    message = str(caught.value)
    assert message == (
        "backend 'declares' declares task 'flow': unknown task 'flow'; "
        'known tasks: detections, tags, segmentation, stereo, tracks'
    )
    assert caught.value.exit_code == 2
    assert (_Declares.detected, _Declares.closed) == (0, 1)  # closed again, never replayed


class _NoTags(NullBackend):
    name: ClassVar[str] = 'no-tags'
    task: ClassVar[str] = 'tags'


def test_a_backend_that_declares_tags_and_returns_none_stops_the_run_in_one_line(tmp_path):
    bag = write_mcap(tmp_path / 'b.mcap', 3)
    with pytest.raises(
        BackendError,
        match=r"^backend 'no_tags' declares task tags but returned no tags \(a TagResult\)$",
    ):
        _run(bag, _NoTags(BackendOptions()))
