"""Recorded detections (and ground truth) holding NaN or inf: left out and counted."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from typing import TYPE_CHECKING

from mcap.writer import Writer

from replaybench.fixtures.scene import Scene
from replaybench.msgs import DETECTION2DARRAY, ros2msg_schema, serialize_detections, serialize_image

if TYPE_CHECKING:
    from pathlib import Path

NS = 1_000_000_000
T0 = 1_700_000_000 * NS


def _bag_with_nonfinite_boxes(path: Path, frames: int = 6) -> Path:
    """Images with ground truth and robot detections, one NaN/inf box in every odd frame."""
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
            gt = list(boxes)
            robot = [b._replace(score=0.9) for b in boxes]
            if i % 2:
                gt.append(boxes[0]._replace(x0=math.inf))
                robot.append(boxes[0]._replace(x1=math.nan))
                robot.append(boxes[0]._replace(score=math.nan))
            writer.add_message(gt_ch, stamp, serialize_detections(stamp, 'cam', gt), stamp)
            writer.add_message(robot_ch, stamp, serialize_detections(stamp, 'cam', robot), stamp)
        writer.finish()
    return path


def test_recorded_boxes_with_nan_or_inf_are_left_out_and_counted(tmp_path):
    bag = _bag_with_nonfinite_boxes(tmp_path / 'robot.mcap')
    out = tmp_path / 'run'
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bag),
            '--backend',
            'recorded',
            '--out',
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert 'Traceback' not in proc.stderr
    assert '/detector/detections: left out 6 detection(s)' in proc.stderr
    assert '/ground_truth/detections: left out 3 detection(s)' in proc.stderr
    for name in ('frames.csv', 'summary.csv'):
        with (out / name).open(newline='') as f:
            cells = [c.strip().lower() for row in csv.reader(f) for c in row]
        assert not {'nan', 'inf', '-inf', 'infinity', '-infinity'} & set(cells), name

    def refuse(constant: str) -> None:
        raise AssertionError(constant)

    json.loads((out / 'run.json').read_text(), parse_constant=refuse)
    assert (out / 'report.html').is_file()
