from __future__ import annotations

import csv
from typing import TYPE_CHECKING

import pytest
from mcap.writer import Writer

from replaybench.errors import UsageError
from replaybench.fixtures.scene import Scene
from replaybench.msgs import DETECTION2DARRAY, ros2msg_schema, serialize_detections, serialize_image
from replaybench.replay.runner import RunConfig, run_benchmark

if TYPE_CHECKING:
    from pathlib import Path

NS = 1_000_000_000
T0 = 1_700_000_000 * NS


def _bag_with_recorded_detections(path: Path, frames: int = 6) -> Path:
    """Images, ground truth, and detections "recorded on the robot" missing one box a frame."""
    scene = Scene((160, 120), 0, 7)
    with path.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='ros2', library='tests')
        image_schema = writer.register_schema(
            'sensor_msgs/msg/Image', 'ros2msg', ros2msg_schema('sensor_msgs/msg/Image').encode()
        )
        det_schema = writer.register_schema(
            DETECTION2DARRAY, 'ros2msg', ros2msg_schema(DETECTION2DARRAY).encode()
        )
        image_ch = writer.register_channel('/camera/image_raw', 'cdr', image_schema)
        gt_ch = writer.register_channel('/ground_truth/detections', 'cdr', det_schema)
        robot_ch = writer.register_channel('/detector/detections', 'cdr', det_schema)
        for i in range(frames):
            stamp = T0 + i * NS // 10
            bgr, boxes = scene.render(i)
            writer.add_message(image_ch, stamp, serialize_image(stamp, 'cam', bgr, 'bgr8'), stamp)
            writer.add_message(gt_ch, stamp, serialize_detections(stamp, 'cam', boxes), stamp)
            robot = [b._replace(score=0.9) for b in boxes[1:]]
            writer.add_message(robot_ch, stamp, serialize_detections(stamp, 'cam', robot), stamp)
        writer.finish()
    return path


def test_recorded_detections_are_scored_like_a_backend_without_latency(tmp_path):
    bag = _bag_with_recorded_detections(tmp_path / 'robot.mcap')
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag], backends=['recorded', 'null'], out_dir=tmp_path / 'run', report=False
        )
    )
    summary = {s.backend: s for s in outcome.run.summary_rows}
    recorded = summary['recorded'].accuracy
    assert recorded is not None
    assert recorded.precision50 == pytest.approx(1.0)
    n_gt = recorded.n_gt
    assert n_gt is not None
    assert recorded.n_det == n_gt - 6  # one box per frame was not recorded
    assert recorded.recall50 == pytest.approx((n_gt - 6) / n_gt)
    assert summary['recorded'].latency_ms_p50 is None
    assert outcome.run_dir is not None
    with (outcome.run_dir / 'frames.csv').open(newline='') as f:
        rows = [r for r in csv.DictReader(f) if r['backend'] == 'recorded']
    assert len(rows) == 6
    assert all(r['latency_ms'] == '' and r['infer_ms'] == '' for r in rows)
    info = next(b for b in outcome.run.backends if b.name == 'recorded').info
    assert info['topic'] == '/detector/detections'
    assert info['frames_matched'] == 6


def test_the_recorded_backend_needs_a_detections_topic(tmp_path):
    bag = _bag_with_recorded_detections(tmp_path / 'robot.mcap', frames=2)
    with pytest.raises(UsageError, match='not in this file'):
        run_benchmark(
            RunConfig(
                inputs=[bag],
                backends=['recorded'],
                out_dir=tmp_path / 'run',
                recorded_topic='/nope',
                report=False,
            )
        )
