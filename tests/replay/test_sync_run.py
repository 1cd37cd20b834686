"""``replaybench run --sync``: real MCAP bags of two and three cameras written here (the mcap
writer, rosbags' CDR), paired by header stamp, reported on stderr and in run.json, and the bad
inputs refused in one line (exit 2)."""

from __future__ import annotations

import csv
import json
from typing import TYPE_CHECKING

import numpy as np
import pytest
from bagtools import image_msg, write_mcap
from typer.testing import CliRunner

from replaybench.backends.base import BackendTraits, backend_traits
from replaybench.backends.null import NullBackend
from replaybench.cli import app
from replaybench.errors import UsageError
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.replay.sync import parse_sync
from replaybench.results.io import read_run_result, to_json

if TYPE_CHECKING:
    from pathlib import Path

runner = CliRunner()

MS = 1_000_000
PERIOD = 33 * MS
EPOCH = 1_700_000_000 * 1_000_000_000
IMAGE = 'sensor_msgs/msg/Image'
LEFT, RIGHT, THIRD = '/rig/left/image_raw', '/rig/right/image_raw', '/rig/third/image_raw'


def _pixels(k: int) -> np.ndarray:
    image = np.full((24, 32, 3), 60, dtype=np.uint8)
    image[4:12, 2 + k % 20 : 10 + k % 20] = (220, 30, 30)  # a red square that moves
    return image


def _bag(path: Path, cameras: dict[str, list[int]]) -> Path:
    """A bag of ``cameras`` (topic -> header stamps), each message logged 2 ms after its
    stamp, in log-time order."""
    messages = [
        (topic, stamp + 2 * MS, image_msg(stamp, _pixels(k), frame_id=topic), IMAGE)
        for topic, stamps in cameras.items()
        for k, stamp in enumerate(stamps)
    ]
    write_mcap(path, sorted(messages, key=lambda m: (m[1], m[0])))
    return path


def _train(n: int, start: int = 0) -> list[int]:
    return [EPOCH + (start + k) * PERIOD for k in range(n)]


@pytest.fixture(scope='module')
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two cameras at 30 Hz, equal stamps; the right one starts 2 frames late and misses one."""
    right = [s for k, s in enumerate(_train(10, start=2)) if k != 5]
    return _bag(tmp_path_factory.mktemp('rig') / 'rig.mcap', {LEFT: _train(12), RIGHT: right})


def _run(*args: str) -> tuple[int, str, str]:
    result = runner.invoke(app, ['run', *args])
    return result.exit_code, result.stdout, result.stderr


def _frames(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / 'frames.csv').open(newline='') as f:
        return list(csv.DictReader(f))


def test_exact_sync_names_each_topic_with_its_unpaired_frames_on_stderr_and_in_run_json(
    rig: Path, tmp_path: Path
) -> None:
    code, _, err = _run(str(rig), '-b', 'hsv', '--sync', 'exact', '--out', str(tmp_path / 'r'))
    assert code == 0, err
    lines = [line for line in err.splitlines() if line.startswith('replaybench: sync')]
    assert lines == [
        f'replaybench: sync exact: 9 set(s) of 2 topic(s); unpaired frames: {LEFT} 3, {RIGHT} 0'
    ]
    sync = json.loads((tmp_path / 'r' / 'run.json').read_text())['sync']
    assert sync['sync'] == 'exact'
    assert sync['backends'] == {'hsv': 'frames'}
    assert sync['stamps_read_s'] >= 0
    (entry,) = sync['inputs']
    assert entry['sets'] == 9
    assert entry['topics'] == [
        {'topic': LEFT, 'frames': 12, 'paired': 9, 'unpaired': 3},
        {'topic': RIGHT, 'frames': 9, 'paired': 9, 'unpaired': 0},
    ]


def test_with_sync_every_backend_still_gets_every_frame_and_gives_the_same_outputs(
    rig: Path, tmp_path: Path
) -> None:
    plain, synced = tmp_path / 'plain', tmp_path / 'synced'
    assert _run(str(rig), '-b', 'hsv', '--out', str(plain), '--no-report')[0] == 0
    assert _run(str(rig), '-b', 'hsv', '--sync', 'approx:4', '--out', str(synced))[0] == 0
    kept = ('input', 'backend', 'topic', 'seq', 'stamp_ns', 'status', 'detections')
    rows = [[tuple(r[k] for k in kept) for r in _frames(d)] for d in (plain, synced)]
    assert rows[0] == rows[1]
    assert len(rows[0]) == 12 + 9
    assert 'sync' not in json.loads((plain / 'run.json').read_text())
    assert (plain / 'outputs.mcap').read_bytes() == (synced / 'outputs.mcap').read_bytes()


def test_approximate_sync_pairs_jittered_stamps_that_exact_sync_refuses(tmp_path: Path) -> None:
    left = _train(20)
    right = [s + (3 * MS if k % 2 else -2 * MS) for k, s in enumerate(left)]
    right[7] += 20 * MS  # beyond the slop of either neighbour
    bag = _bag(tmp_path / 'jitter.mcap', {LEFT: left, RIGHT: right})
    code, _, err = _run(str(bag), '-b', 'null', '--sync', 'approx:5', '--out', str(tmp_path / 'a'))
    assert code == 0, err
    assert (
        'replaybench: sync approx:5: 19 set(s) of 2 topic(s), largest spread 3.000 ms; '
        f'unpaired frames: {LEFT} 1, {RIGHT} 1'
    ) in err.splitlines()
    code, out, err = _run(str(bag), '-b', 'null', '--sync', 'exact', '--out', str(tmp_path / 'e'))
    assert code == 2
    assert out == ''
    assert len(err.strip().splitlines()) == 1, err
    assert f'--sync exact: topics {LEFT}, {RIGHT} share no header stamp' in err
    assert not (tmp_path / 'e').exists()


def test_three_cameras_group_into_sets_of_three(tmp_path: Path) -> None:
    bag = _bag(
        tmp_path / 'three.mcap',
        {LEFT: _train(8), RIGHT: _train(8), THIRD: [s + MS for s in _train(7, start=1)]},
    )
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=None, sync=parse_sync('approx:1'))
    )
    sync = outcome.run.sync
    assert sync is not None
    assert [(t.topic, t.unpaired) for t in sync.inputs[0].topics] == [
        (LEFT, 1),
        (RIGHT, 1),
        (THIRD, 0),
    ]
    assert sync.inputs[0].sets == 7
    assert sync.inputs[0].spread_ms_max == pytest.approx(1.0)


def test_a_sync_topic_that_the_bag_does_not_hold_is_refused_in_one_line(
    rig: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'r'
    code, _, err = _run(
        str(rig), '-b', 'null', '-t', LEFT, '-t', '/rig/nope', '--sync', 'exact', '--out', str(out)
    )
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert 'no image topic named /rig/nope to pair' in err
    assert 'Traceback' not in err
    assert not out.exists()


@pytest.mark.parametrize('spec', ['approx', 'approx:-3', 'nearest'])
def test_a_malformed_sync_is_refused_in_one_line(rig: Path, tmp_path: Path, spec: str) -> None:
    code, _, err = _run(str(rig), '-b', 'null', '--sync', spec, '--out', str(tmp_path / 'r'))
    assert code == 2
    assert err.strip().splitlines() == [
        f"replaybench: error: invalid --sync '{spec}': use exact or approx:SLOP_MS (e.g. approx:5)"
    ]


def test_sync_on_one_topic_says_so_once_and_pairs_nothing(rig: Path, tmp_path: Path) -> None:
    other = _bag(tmp_path / 'other.mcap', {LEFT: _train(4)})
    code, _, err = _run(
        str(rig),
        str(other),
        '-b',
        'null',
        '-t',
        LEFT,
        '--sync',
        'exact',
        '--out',
        str(tmp_path) + '/r',
    )
    assert code == 0, err
    said = [line for line in err.splitlines() if 'nothing to pair' in line]
    assert said == [
        (
            f'replaybench: warning: --sync exact with one topic ({LEFT}): nothing to pair, '
            'each frame is a set of one'
        )
    ]
    sync = json.loads((tmp_path / 'r' / 'run.json').read_text())['sync']
    assert [(i['sets'], i['topics'][0]['unpaired']) for i in sync['inputs']] == [(12, 0), (4, 0)]


def test_a_run_json_with_a_sync_section_reads_back_and_one_without_it_reads_as_none(
    rig: Path, tmp_path: Path
) -> None:
    assert _run(str(rig), '-b', 'null', '--sync', 'exact', '--out', str(tmp_path / 'r'))[0] == 0
    path = tmp_path / 'r' / 'run.json'
    document = json.loads(path.read_text())
    result = read_run_result(path)
    assert result.sync is not None
    assert result.sync.inputs[0].topics[0].unpaired == 3
    assert to_json(result) == document
    del document['sync']  # as a run folder written before --sync existed
    older = tmp_path / 'older.json'
    older.write_text(json.dumps(document))
    assert read_run_result(older).sync is None


class _SetsBackend(NullBackend):
    takes_frame_sets = True


def test_a_backend_that_declares_it_takes_frame_sets_is_refused_without_sync_before_any_frame(
    rig: Path,
) -> None:
    assert backend_traits(_SetsBackend).takes_frame_sets
    assert BackendTraits().takes_frame_sets is False
    with pytest.raises(UsageError, match='takes synchronised frame sets, which only --sync'):
        run_benchmark(
            RunConfig(inputs=[rig], backends=['null'], out_dir=None),
            backend_factory=lambda _name, options: _SetsBackend(options),
        )
