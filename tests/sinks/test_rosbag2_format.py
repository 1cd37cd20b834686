"""``replaybench run --format rosbag2``: the run folder opens as a rosbag2 bag."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import ConnectionExtRosbag2
from rosbags.rosbag2 import Reader as Rosbag2Reader

BAG = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'rgb8.bag'


def _replaybench(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
    )


def test_format_rosbag2_makes_the_run_folder_a_bag_that_rosbags_reads(tmp_path: Path) -> None:
    out = tmp_path / 'run'
    done = _replaybench(
        'run', str(BAG), '-b', 'hsv', '--annotations', '--format', 'rosbag2', '--out', str(out)
    )
    assert done.returncode == 0, done.stderr
    assert (out / 'metadata.yaml').is_file()
    with Rosbag2Reader(out) as bag:
        assert bag.message_count == 30  # 10 CameraInfo, 10 detections, 10 annotations
        exts = [c.ext for c in bag.connections]
        assert all(isinstance(e, ConnectionExtRosbag2) and e.offered_qos_profiles for e in exts)
    with AnyReader([out]) as reader:
        decoded: list[Any] = [
            reader.deserialize(raw, c.msgtype)
            for c, _, raw in reader.messages()
            if c.topic.endswith('/annotations')
        ]
    assert len(decoded) == 10
    assert all(m.points for m in decoded)
    settings = json.loads((out / 'run.json').read_text())['settings']
    assert settings['detections_format'] == 'rosbag2'


def test_the_default_format_writes_no_metadata_yaml(tmp_path: Path) -> None:
    out = tmp_path / 'run'
    done = _replaybench('run', str(BAG), '-b', 'null', '--no-report', '--out', str(out))
    assert done.returncode == 0, done.stderr
    assert not (out / 'metadata.yaml').exists()
    assert json.loads((out / 'run.json').read_text())['settings']['detections_format'] == 'mcap'


def test_an_unknown_format_is_refused_with_one_line_and_exit_2(tmp_path: Path) -> None:
    out = tmp_path / 'run'
    done = _replaybench('run', str(BAG), '-b', 'null', '--format', 'ros3', '--out', str(out))
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "replaybench: error: unknown --format 'ros3': use mcap or rosbag2"
    ]
    assert not out.exists()
