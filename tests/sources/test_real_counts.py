"""The real recordings in ../shared/real: ``info`` and ``run --backend null`` count the frames the
official readers count (rosbags AnyReader for ROS 1 and rosbag2, the mcap reader for MCAP)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from replaybench.replay.runner import RunConfig, run_benchmark

REPO = Path(__file__).resolve().parents[2]
SHARED_REAL = (REPO / '..' / 'shared' / 'real').resolve()
IMAGE_TYPES = {
    'sensor_msgs/msg/Image',
    'sensor_msgs/msg/CompressedImage',
    'foxglove.RawImage',
    'foxglove.CompressedImage',
}


def _recordings() -> list[Path]:
    """Every bag, rosbag2 folder and MCAP under ../shared/real (bags and derived rewraps)."""
    if not SHARED_REAL.is_dir():
        return []
    found = sorted((SHARED_REAL / 'bags').rglob('*.bag'))
    derived = SHARED_REAL / 'derived'
    found += sorted(p for p in derived.iterdir() if (p / 'metadata.yaml').is_file())
    found += sorted(derived.glob('*.mcap'))
    return found


RECORDINGS = _recordings()
skip_without_shared = pytest.mark.skipif(
    not RECORDINGS, reason=f'{SHARED_REAL} not present (real recordings are optional)'
)


def _official_counts(path: Path) -> dict[str, int]:
    """Image messages per topic by the official reader of the format."""
    if path.suffix == '.mcap':
        with path.open('rb') as stream:
            summary = make_reader(stream).get_summary()
        assert summary is not None
        assert summary.statistics is not None
        counts = {}
        for channel_id, n in summary.statistics.channel_message_counts.items():
            channel = summary.channels[channel_id]
            if summary.schemas[channel.schema_id].name in IMAGE_TYPES:
                counts[channel.topic] = n
        return counts
    with AnyReader([path]) as reader:
        return {c.topic: c.msgcount for c in reader.connections if c.msgtype in IMAGE_TYPES}


def _info_counts(path: Path) -> dict[str, int]:
    """``replaybench info``'s image topics and message counts, from its output."""
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'info', str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
    )
    assert done.returncode == 0, done.stderr
    rows = done.stdout.split('camera topics:', 1)[1].splitlines()
    counts = {}
    for row in rows:
        match = re.match(r'\s+(\S+)\s+(\S+)\s+(\d+) msgs', row)
        if match and match[2] in IMAGE_TYPES:  # the CameraInfo topics are listed too
            counts[match[1]] = int(match[3])
    return counts


@skip_without_shared
@pytest.mark.parametrize('path', RECORDINGS, ids=[p.name for p in RECORDINGS])
def test_info_counts_the_frames_the_official_reader_counts(path: Path) -> None:
    official = _official_counts(path)
    assert official
    assert _info_counts(path) == official


@skip_without_shared
@pytest.mark.parametrize('path', RECORDINGS, ids=[p.name for p in RECORDINGS])
def test_a_null_run_replays_every_frame_the_official_reader_counts(
    path: Path, tmp_path: Path
) -> None:
    official = _official_counts(path)
    outcome = run_benchmark(
        RunConfig(
            inputs=[path],
            backends=['null'],
            out_dir=tmp_path / 'run',
            topics=sorted(official),
            report=False,
            annotations=True,
            copy_images=True,
        )
    )
    rows = outcome.run.summary_rows
    assert {s.topic: s.frames for s in rows if s.topic != 'rig'} == official
    # several cameras: their rig row holds every frame of them, once
    rig = [s.frames for s in rows if s.topic == 'rig']
    assert rig == ([sum(official.values())] if len(official) > 1 else [])
    assert outcome.run_dir is not None
    with (outcome.run_dir / 'outputs.mcap').open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    assert summary.statistics is not None
    written = {
        summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()
    }
    for topic, n in official.items():
        assert written[f'/replaybench/null{topic}/detections'] == n
        assert written[f'/replaybench/null{topic}/annotations'] == n
        assert written[topic] == n  # the copied images
