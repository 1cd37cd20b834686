from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from replaybench.cli import app

REPO = Path(__file__).resolve().parents[1]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
runner = CliRunner()


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, 'PYTHONWARNINGS': 'ignore'}
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=False,
    )


def test_run_writes_the_five_outputs_and_hsv_matches_the_ground_truth(tmp_path):
    out = tmp_path / 'run'
    result = runner.invoke(
        app, ['run', str(RAW), '--backend', 'hsv', '--backend', 'null', '--out', str(out)]
    )
    assert result.exit_code == 0, result.output
    for name in ('outputs.mcap', 'frames.csv', 'summary.csv', 'run.json', 'report.html'):
        assert (out / name).is_file(), name
    assert list((out / 'samples').iterdir())
    run = json.loads((out / 'run.json').read_text())
    assert run['status'] == 'complete'
    hsv = next(s for s in run['summary'] if s['backend'] == 'hsv')
    assert hsv['accuracy']['precision50'] >= 0.9
    assert hsv['accuracy']['recall50'] >= 0.8
    null = next(s for s in run['summary'] if s['backend'] == 'null')
    assert null['accuracy']['recall50'] == 0.0
    with (out / 'frames.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    frames = run['inputs'][0]['topics'][0]['count']
    assert len(rows) == 2 * frames
    assert 'Report:' in result.output


def test_two_runs_give_identical_detections_in_the_same_order(tmp_path):
    from mcap.reader import make_reader

    payloads = []
    for name in ('a', 'b'):
        out = tmp_path / name
        result = runner.invoke(
            app, ['run', str(RAW), '-b', 'hsv', '--out', str(out), '--no-report']
        )
        assert result.exit_code == 0, result.output
        with (out / 'outputs.mcap').open('rb') as f:
            payloads.append(
                [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]
            )
    assert payloads[0] == payloads[1]
    assert any(len(p[2]) > 100 for p in payloads[0])


@pytest.mark.parametrize(
    ('name', 'content'),
    [
        ('empty.mcap', b''),
        ('random.mcap', os.urandom(4096)),
        ('notes.mcap', b'this is a text file, not a bag\n' * 20),
        ('random.bag', os.urandom(2048)),
        ('random.db3', os.urandom(2048)),
    ],
)
def test_an_unreadable_input_exits_2_with_one_line_and_no_output_folder(tmp_path, name, content):
    bag = tmp_path / name
    bag.write_bytes(content)
    out = tmp_path / 'run'
    result = _cli('run', str(bag), '--backend', 'hsv', '--out', str(out))
    assert result.returncode == 2
    assert 'Traceback' not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not out.exists()


def test_a_missing_input_exits_2(tmp_path):
    result = _cli(
        'run', str(tmp_path / 'nope.mcap'), '--backend', 'hsv', '--out', str(tmp_path / 'run')
    )
    assert result.returncode == 2
    assert 'nope.mcap' in result.stderr
    assert 'Traceback' not in result.stderr


def test_an_unknown_backend_exits_2_naming_the_known_ones(tmp_path):
    result = runner.invoke(
        app, ['run', str(RAW), '--backend', 'yolo9000', '--out', str(tmp_path / 'r')]
    )
    assert result.exit_code == 2
    assert 'hsv' in result.output


def test_info_lists_camera_topics_with_sizes_and_encodings():
    result = runner.invoke(app, ['info', str(REPO / 'fixtures' / 'bags' / 'two_camera.mcap')])
    assert result.exit_code == 0, result.output
    assert '/cam_left/image_raw' in result.output
    assert '/cam_right/image_raw' in result.output
    assert '/ground_truth/detections' in result.output


def test_backends_says_which_are_available():
    result = runner.invoke(app, ['backends'])
    assert result.exit_code == 0
    assert 'hsv' in result.output
    assert 'null' in result.output
    assert 'available' in result.output


def test_every_command_help_opens_with_a_purpose_and_an_example():
    for command in ('run', 'info', 'backends', 'fixtures', 'report'):
        result = runner.invoke(app, [command, '--help'])
        assert result.exit_code == 0
        assert 'Example: replaybench' in result.output, command


def test_report_re_renders_from_the_run_folder_alone(tmp_path):
    out = tmp_path / 'run'
    assert (
        runner.invoke(
            app, ['run', str(RAW), '-b', 'null', '--out', str(out), '--no-report']
        ).exit_code
        == 0
    )
    moved = tmp_path / 'elsewhere'
    out.rename(moved)
    result = runner.invoke(app, ['report', str(moved)])
    assert result.exit_code == 0, result.output
    assert (moved / 'report.html').stat().st_size > 1000


def test_every_bundled_fixture_bag_runs(tmp_path, fixture_bags):
    bags = sorted(
        p for p in fixture_bags.iterdir() if p.suffix in {'.mcap', '.bag', '.db3'} or p.is_dir()
    )
    assert len(bags) >= 5
    # a recorded label-mask topic is an Image topic like a camera's: that bag's camera is named
    topics = {'live_masks.mcap': ['--topic', '/camera/image_raw/compressed']}
    for i, bag in enumerate(bags):
        result = runner.invoke(
            app,
            [
                'run', str(bag), '-b', 'hsv', '--out', str(tmp_path / str(i)), '--no-report',
                *topics.get(bag.name, []),
            ],
        )  # fmt: skip
        assert result.exit_code == 0, (bag, result.output)
        run = json.loads((tmp_path / str(i) / 'run.json').read_text())
        # each camera scored; a rig row (several cameras together) keeps no accuracy
        cameras = [s for s in run['summary'] if s['topic'] != 'rig']
        assert all(s['accuracy'] and s['accuracy']['recall50'] > 0.5 for s in cameras), bag
        assert all(s['accuracy'] is None for s in run['summary'] if s['topic'] == 'rig'), bag


def test_every_real_recording_runs_or_explains_itself(tmp_path, shared_real):
    bags = sorted(shared_real.glob('bags/ros1/*.bag')) + sorted(
        p for p in (shared_real / 'derived').iterdir() if p.suffix == '.mcap' or p.is_dir()
    )
    assert bags
    for i, bag in enumerate(bags):
        out = tmp_path / str(i)
        result = _cli('run', str(bag), '-b', 'hsv', '--out', str(out), '--no-report')
        assert 'Traceback' not in result.stderr, (bag, result.stderr)
        if 'compressedDepth' in bag.name:
            assert result.returncode == 2, (bag, result.stderr)
            assert '--topic /spot/depth/frontleft/image/compressedDepth' in result.stderr
            result = _cli(
                'run',
                str(bag),
                '-b',
                'hsv',
                '--out',
                str(out),
                '--no-report',
                '--topic',
                '/spot/depth/frontleft/image/compressedDepth',
            )
        assert result.returncode == 0, (bag, result.stderr)
        run = json.loads((out / 'run.json').read_text())
        assert run['counts']['skipped'] == 0, bag
