"""The stereo task's truth from elsewhere than /ground_truth/disparity: a folder of Middlebury
``.pfm`` or KITTI ``.png`` files named by stamp, another disparity topic, a depth topic turned
into disparity with each output's focal length and baseline; and what is refused."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import TYPE_CHECKING

import numpy as np
import pytest

import replaybench as rb
from replaybench.decode import decode_image
from replaybench.fixtures.stereo import STEREO_BASELINE_M, rectified_camera_infos, write_stereo_mcap
from replaybench.fixtures.writer import FixtureMessage, write_ros2_mcap
from replaybench.msgs import IMAGE, serialize_image
from replaybench.sources import open_source
from replaybench.stereo.files import write_kitti_png, write_pfm

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    import numpy.typing as npt

FRAMES = 3
TRUTH = '/ground_truth/disparity'
SIZE = (320, 240)


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_stereo_mcap(tmp_path_factory.mktemp('bag') / 'stereo.mcap', FRAMES, SIZE)


@pytest.fixture(scope='module')
def reference(bag: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, float | None]:
    """sgbm's pooled figures against the bag's own truth topic."""
    out = tmp_path_factory.mktemp('runs') / 'topic'
    rb.run(bag, backends=['sgbm'], out=out, report=False)
    (row,) = json.loads((out / 'run.json').read_text())['summary']
    metrics: dict[str, float | None] = row['task_metrics']
    return metrics


def _messages(bag: Path) -> list[FixtureMessage]:
    from mcap.reader import make_reader

    with bag.open('rb') as f:
        return [
            FixtureMessage(m.log_time, c.topic, s.name, m.data)
            for s, c, m in make_reader(f).iter_messages()
            if s is not None
        ]


def _truths(bag: Path) -> list[tuple[str, int, npt.NDArray[np.float32]]]:
    """(frame_id, stamp, disparity) of each truth message."""
    found = []
    with open_source(bag) as source:
        for raw in source.messages(topics=[TRUTH]):
            frame = decode_image(raw)
            found.append((frame.frame_id, frame.stamp_ns, np.asarray(frame.image)))
    return found


def _without_truth(bag: Path, out: Path, extra: Sequence[FixtureMessage] = ()) -> Path:
    kept = [m for m in _messages(bag) if m.topic != TRUTH] + list(extra)
    kept.sort(key=lambda m: m.log_time_ns)
    return write_ros2_mcap(out, kept)


def _figures(bag: Path, out: Path, *options: str) -> dict[str, float | None]:
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'run', str(bag), '--backend', 'sgbm',
         '--no-report', '--out', str(out), *options],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    (row,) = json.loads((out / 'run.json').read_text())['summary']
    metrics: dict[str, float | None] = row['task_metrics']
    return metrics


def test_a_folder_of_pfm_files_named_by_stamp_scores_as_the_truth_topic_does(
    bag: Path, reference: dict[str, float | None], tmp_path: Path
) -> None:
    folder = tmp_path / 'gt'
    folder.mkdir()
    for _, stamp, disparity in _truths(bag):
        write_pfm(folder / f'{stamp}.pfm', disparity)
    bare = _without_truth(bag, tmp_path / 'bare.mcap')
    figures = _figures(bare, tmp_path / 'run', '--ground-truth-disparity', str(folder))
    assert figures == reference


def test_kitti_pngs_score_within_their_quantisation_of_a_256th_pixel(
    bag: Path, reference: dict[str, float | None], tmp_path: Path
) -> None:
    folder = tmp_path / 'gt'
    folder.mkdir()
    for _, stamp, disparity in _truths(bag):
        write_kitti_png(folder / f'{stamp}.png', disparity)
    figures = _figures(bag, tmp_path / 'run', '--ground-truth-disparity', str(folder))
    epe, ref = figures['epe'], reference['epe']
    assert epe is not None
    assert ref is not None
    assert abs(epe - ref) <= 1 / 256
    assert figures['density'] == pytest.approx(reference['density'], abs=1e-3)


def test_another_disparity_topic_is_named_and_the_default_one_left_alone(
    bag: Path, reference: dict[str, float | None], tmp_path: Path
) -> None:
    moved = [
        FixtureMessage(m.log_time_ns, '/gt/disp', m.msgtype, m.data)
        for m in _messages(bag)
        if m.topic == TRUTH
    ]
    renamed = _without_truth(bag, tmp_path / 'moved.mcap', moved)
    assert _figures(renamed, tmp_path / 'run', '--ground-truth-disparity', '/gt/disp') == reference


@pytest.mark.parametrize('encoding', ['32FC1', '16UC1'])
def test_a_depth_topic_is_made_disparity_with_the_outputs_focal_length_and_baseline(
    bag: Path, reference: dict[str, float | None], tmp_path: Path, encoding: str
) -> None:
    left, _ = rectified_camera_infos(SIZE, 0)
    f = left.p[0]
    depth_messages = []
    for (frame_id, stamp, disparity), m in zip(
        _truths(bag), (m for m in _messages(bag) if m.topic == TRUTH), strict=True
    ):
        with np.errstate(divide='ignore'):
            z = np.where(disparity > 0, f * STEREO_BASELINE_M / disparity.astype(np.float64), 0)
        image = (
            z.astype(np.float32) if encoding == '32FC1' else np.round(z * 1000).astype(np.uint16)
        )
        data = serialize_image(stamp, frame_id, image, encoding)
        depth_messages.append(FixtureMessage(m.log_time_ns, '/gt/depth', IMAGE, data))
    with_depth = _without_truth(bag, tmp_path / 'depth.mcap', depth_messages)
    figures = _figures(with_depth, tmp_path / 'run', '--ground-truth-depth', '/gt/depth')
    tolerance = 1e-4 if encoding == '32FC1' else 2e-2  # millimetres at up to 4 m
    for name in ('epe', 'bad2', 'density'):
        value, ref = figures[name], reference[name]
        assert value is not None
        assert ref is not None
        assert value == pytest.approx(ref, abs=tolerance), name


@pytest.mark.parametrize(
    ('options', 'line'),
    [
        (['--ground-truth-disparity', '/gt/none'], 'ground-truth topic /gt/none is not a topic'),
        (['--ground-truth-depth', '/gt/none'], 'ground-truth topic /gt/none is not a topic'),
        (
            ['--ground-truth-disparity', '/gt/a', '--ground-truth-depth', '/gt/b'],
            'give --ground-truth-disparity or --ground-truth-depth, not both',
        ),
    ],
)
def test_truth_options_that_cannot_be_served_are_one_line_and_exit_2(
    bag: Path, tmp_path: Path, options: list[str], line: str
) -> None:
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'run', str(bag), '--backend', 'sgbm',
         '--no-report', '--out', str(tmp_path / 'run'), *options],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2
    (last,) = done.stderr.strip().splitlines()[-1:]
    assert last.startswith('replaybench: error: ')
    assert line in last
    assert 'Traceback' not in done.stderr


def test_a_folder_without_truth_files_is_one_line_and_exit_2(bag: Path, tmp_path: Path) -> None:
    empty = tmp_path / 'empty'
    empty.mkdir()
    (empty / 'notes.txt').write_text('nothing here')
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'run', str(bag), '--backend', 'sgbm',
         '--no-report', '--out', str(tmp_path / 'run'), '--ground-truth-disparity', str(empty)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        f'replaybench: error: {empty}: no ground-truth disparity (<stamp_ns>.pfm or .png) in '
        'this folder'
    )
