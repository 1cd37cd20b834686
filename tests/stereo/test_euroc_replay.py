"""Real stereo data replayed: 24 EuRoC pairs (``../shared/real/euroc_micro``, a 20 Hz
VI-Sensor, unrectified) written into an MCAP with their CameraInfo pairs (in the test, never
committed) and replayed through ``sgbm`` at the recorded rate, rectified from the CameraInfo:
each processed pair's DisparityImage is what the bare library gives for it."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from stereodata import EUROC, euroc_camera_infos, euroc_pair, need

from replaybench.fixtures.writer import FixtureMessage, write_ros2_mcap
from replaybench.msgs import CAMERA_INFO, IMAGE, serialize_camera_info, serialize_image, typestore
from replaybench.stereo import Matcher, stereo_pair
from replaybench.stereo.msgs import DISPARITY_IMAGE

if TYPE_CHECKING:
    from pathlib import Path

PAIRS = 24
LEFT, RIGHT = '/euroc/left/image_raw', '/euroc/right/image_raw'


def _stamps() -> list[int]:
    names = sorted((EUROC / 'cam0' / 'data').glob('*.png'))
    return [int(p.stem) for p in names[:PAIRS]]


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    need(EUROC)
    infos = euroc_camera_infos()
    messages = []
    for i, stamp in enumerate(_stamps()):
        for topic, info, image in zip((LEFT, RIGHT), infos, euroc_pair(i), strict=True):
            side = topic.rsplit('/', 1)[0]
            stamped = replace(info, stamp_ns=stamp)
            messages.append(
                FixtureMessage(
                    stamp, f'{side}/camera_info', CAMERA_INFO, serialize_camera_info(stamped, seq=i)
                )
            )
            data = serialize_image(stamp, info.frame_id, image, 'mono8', seq=i)
            messages.append(FixtureMessage(stamp, topic, IMAGE, data))
    return write_ros2_mcap(tmp_path_factory.mktemp('euroc') / 'euroc.mcap', messages)


@pytest.fixture(scope='module')
def run_dir(bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('runs') / 'euroc'
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'run', str(bag), '--backend', 'sgbm',
         '--rate', 'recorded', '--warmup', '2', '--no-report', '--out', str(out)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return out


def _disparities(run: Path) -> dict[int, Any]:
    from mcap.reader import make_reader

    store = typestore(False)
    found = {}
    with (run / 'outputs.mcap').open('rb') as f:
        topic = f'/replaybench/sgbm{LEFT}/disparity'
        for _, _, message in make_reader(f).iter_messages(topics=[topic]):
            found[message.log_time] = store.deserialize_cdr(message.data, DISPARITY_IMAGE)
    return found


def test_euroc_pairs_replay_at_their_recorded_rate_each_pair_once(run_dir: Path) -> None:
    document = json.loads((run_dir / 'run.json').read_text())
    assert document['settings']['rate'] == 'recorded'
    (row,) = document['summary']
    assert row['topic'] == LEFT
    assert row['frames'] == PAIRS
    assert row['processed'] + row['dropped'] == PAIRS
    assert row['processed'] >= 3
    written = _disparities(run_dir)
    assert len(written) == row['processed']
    stamps = _stamps()
    # the release times follow the log: 20 Hz (50 ms apart, to the camera's jitter)
    assert np.median(np.diff(stamps)) == pytest.approx(50e6, rel=0.01)
    assert set(written) <= set(stamps)


def test_each_replayed_euroc_disparity_is_the_bare_rectify_and_match_of_its_pair(
    run_dir: Path,
) -> None:
    pair = stereo_pair(*euroc_camera_infos())
    assert not pair.rectified
    rectifier = pair.rectifier()
    matcher = Matcher('sgbm')
    index = {stamp: i for i, stamp in enumerate(_stamps())}
    written = _disparities(run_dir)
    for stamp, message in sorted(written.items())[:3]:
        left, right = rectifier.rectify(*euroc_pair(index[stamp]))
        bare = matcher.compute(left, right)
        image = message.image
        replayed = np.frombuffer(bytes(image.data), '<f4').reshape(image.height, image.width)
        expected = np.where(np.isnan(bare), np.float32(message.min_disparity - 1), bare)
        assert np.array_equal(replayed, expected)
        assert message.t == pytest.approx(pair.baseline)
        assert message.t == pytest.approx(0.110, abs=0.002)
        estimated = np.isfinite(bare).mean()
        assert estimated > 0.3  # real texture matched after rectification
