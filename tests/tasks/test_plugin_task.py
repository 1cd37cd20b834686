"""A task registered from outside replaybench (``tests/tasks/plugin/rb_brightness``, through the
``replaybench.tasks`` and ``replaybench.backends`` entry-point groups) runs end to end: run,
summary.csv, run.json, outputs.mcap, the report, ``load_run``, ``compare --fail-if`` on its
metric and a sweep cell, with nothing in ``replaybench/`` naming it."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bagtools import TS, Header, Time, image_msg, write_mcap

PLUGIN = Path(__file__).parent / 'plugin'
FRAMES = 30
TOPIC = '/cam/image_raw'
ENTRY_POINTS = """\
[replaybench.backends]
brightness = rb_brightness.backend:BrightnessBackend
brightness-biased = rb_brightness.backend:BiasedBrightnessBackend

[replaybench.tasks]
brightness = rb_brightness.task:TASK
"""


def _levels() -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    return [
        np.clip(rng.normal(40 + 5 * i, 20, (24, 32, 3)), 0, 255).astype(np.uint8)
        for i in range(FRAMES)
    ]


@pytest.fixture(scope='module')
def plugin(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The plugin installed as a distribution (its ``.dist-info`` on ``PYTHONPATH``) and a bag
    of 30 frames with their true mean grey level on ``/ground_truth/brightness``."""
    root = tmp_path_factory.mktemp('plugin')
    dist = root / 'site' / 'rb_brightness-0.1.dist-info'
    dist.mkdir(parents=True)
    (dist / 'METADATA').write_text(
        'Metadata-Version: 2.1\nName: rb-brightness\nVersion: 0.1\n', encoding='utf-8'
    )
    (dist / 'entry_points.txt').write_text(ENTRY_POINTS, encoding='utf-8')
    illuminance = TS.types['sensor_msgs/msg/Illuminance']
    messages: list[tuple[str, int, object, str]] = []
    for i, pixels in enumerate(_levels()):
        stamp = 1_700_000_000 * 10**9 + i * 33_333_333
        messages.append((TOPIC, stamp, image_msg(stamp, pixels), 'sensor_msgs/msg/Image'))
        truth = illuminance(
            header=Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id='cam'),
            illuminance=float(np.mean(pixels, dtype=np.float64)),
            variance=0.0,
        )
        messages.append(('/ground_truth/brightness', stamp, truth, 'sensor_msgs/msg/Illuminance'))
    bag = root / 'levels.mcap'
    write_mcap(bag, messages)
    paths = [str(root / 'site'), str(PLUGIN), os.environ.get('PYTHONPATH', '')]
    env = {k: v for k, v in os.environ.items() if not k.startswith('RAY_')}
    env.update(PYTHONPATH=os.pathsep.join(p for p in paths if p), HOME=str(root))
    return {'root': root, 'bag': bag, 'env': env}


def _cli(plugin: dict[str, Any], *args: str, expect: int = 0) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        env=plugin['env'],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == expect, proc.stdout[-2000:] + proc.stderr[-4000:]
    assert 'Traceback' not in proc.stderr
    return proc


@pytest.fixture(scope='module')
def run_dir(plugin: dict[str, Any]) -> Path:
    out: Path = plugin['root'] / 'run'
    _cli(
        plugin,
        'run',
        str(plugin['bag']),
        '--backend',
        'brightness',
        '--backend',
        'brightness-biased',
        '--backend',
        'hsv',
        '--out',
        str(out),
    )
    return out


def test_the_plugins_task_and_backends_are_listed_beside_the_built_in_ones(
    plugin: dict[str, Any],
) -> None:
    listed = _cli(plugin, 'backends').stdout
    assert 'brightness-biased' in listed
    code = 'from replaybench.tasks import task_names; print(task_names())'
    names = subprocess.run(
        [sys.executable, '-c', code], env=plugin['env'], capture_output=True, text=True, check=True
    ).stdout
    assert (
        names.strip() == "['detections', 'tags', 'segmentation', 'stereo', 'tracks', 'brightness']"
    )


def test_summary_csv_holds_the_tasks_metric_after_the_known_columns(run_dir: Path) -> None:
    with (run_dir / 'summary.csv').open(newline='', encoding='utf-8') as file:
        rows = list(csv.reader(file))
    assert rows[0][-1] == 'brightness_error'
    assert rows[0][-2] == 'tag_rot_err_deg'  # the known columns stay where they were
    values = {row[0]: row[-1] for row in rows[1:]}
    assert values == {'brightness': '0.0000', 'brightness_biased': '4.0000', 'hsv': ''}


def test_run_json_and_load_run_give_the_tasks_metric_per_row(run_dir: Path) -> None:
    import replaybench as rb

    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    metrics = {row['backend']: row.get('task_metrics') for row in document['summary']}
    assert metrics == {
        'brightness': {'brightness_error': 0.0},
        'brightness_biased': {'brightness_error': 4.0},
        'hsv': None,
    }
    loaded = rb.load_run(run_dir)
    assert [s.metric('brightness_error') for s in loaded.summary_rows] == [0.0, 4.0, None]
    table = loaded.summary
    assert list(table['brightness_error'].isna()) == [False, False, True]
    assert table['brightness_error'].iloc[1] == 4.0


def test_frames_csv_holds_the_tasks_frame_column_after_the_known_ones(run_dir: Path) -> None:
    import replaybench as rb
    from replaybench.results.records import FRAMES_CSV_COLUMNS, read_frames_csv

    with (run_dir / 'frames.csv').open(newline='', encoding='utf-8') as file:
        rows = list(csv.reader(file))
    assert tuple(rows[0]) == (*FRAMES_CSV_COLUMNS, 'brightness_abs_error')
    cells = {(row[1], row[3]): row[-1] for row in rows[1:]}
    assert {cells[('brightness', str(i))] for i in range(FRAMES)} == {'0.0000'}
    assert {cells[('brightness_biased', str(i))] for i in range(FRAMES)} == {'4.0000'}
    assert {cells[('hsv', str(i))] for i in range(FRAMES)} == {''}
    records = read_frames_csv(run_dir / 'frames.csv')
    assert records[0].task_values == {'brightness_abs_error': 0.0}
    errors = rb.load_run(run_dir).frames.groupby('backend')['brightness_abs_error']
    assert errors.max()['brightness'] == 0.0
    assert errors.max()['brightness_biased'] == 4.0
    assert errors.count()['hsv'] == 0


def test_outputs_mcap_holds_each_frames_output_on_the_tasks_channel(run_dir: Path) -> None:
    from mcap.reader import make_reader

    with (run_dir / 'outputs.mcap').open('rb') as stream:
        reader = make_reader(stream)
        found: dict[str, list[float]] = {}
        for schema, channel, message in reader.iter_messages():
            if channel.topic.endswith('/brightness'):
                assert schema is not None
                assert schema.name == 'sensor_msgs/msg/Illuminance'
                msg: Any = TS.deserialize_cdr(message.data, schema.name)
                found.setdefault(channel.topic, []).append(msg.illuminance)
    expected = [float(np.mean(p, dtype=np.float64)) for p in _levels()]
    assert found['/replaybench/brightness/cam/image_raw/brightness'] == pytest.approx(expected)
    biased = found['/replaybench/brightness_biased/cam/image_raw/brightness']
    assert biased == pytest.approx([level + 4 for level in expected])


def test_the_report_shows_the_tasks_main_metric_in_the_summary_table(run_dir: Path) -> None:
    html = (run_dir / 'report.html').read_text(encoding='utf-8')
    table = html[html.index('id="summary-table"') :]
    table = table[: table.index('</table>')]
    assert '<th class="n">bright. err</th>' in table
    assert table.count('>0.000</td>') == 1
    assert table.count('>4.000</td>') == 1
    headline = html[html.index('id="headline-table"') :]
    headline = headline[: headline.index('</table>')]
    # the most accurate backend by the task's main figure, lower being better
    assert '<th class="n">brightness error (grey levels)</th>' in headline
    assert '<b>0.000</b>' in headline


def test_compare_gates_on_the_tasks_metric(plugin: dict[str, Any]) -> None:
    run_dir = plugin['root'] / 'pair'
    _cli(
        plugin,
        'run',
        str(plugin['bag']),
        '--backend',
        'brightness',
        '--backend',
        'brightness-biased',
        '--no-report',
        '--out',
        str(run_dir),
    )
    failed = _cli(
        plugin,
        'compare',
        str(run_dir),
        '--baseline-backend',
        'brightness',
        '--fail-if',
        'brightness_error > 1',
        expect=1,
    )
    gate = [line for line in failed.stderr.splitlines() if 'gate: FAIL' in line]
    assert len(gate) == 1, failed.stderr
    assert 'brightness_biased' in gate[0]
    assert 'brightness error (grey levels)' in gate[0]
    passed = _cli(
        plugin,
        'compare',
        str(run_dir),
        '--baseline-backend',
        'brightness',
        '--fail-if',
        'brightness_error > 10',
    )
    assert 'brightness_biased' in passed.stdout


def test_a_sweep_cell_reports_the_tasks_metric(plugin: dict[str, Any]) -> None:
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    out = plugin['root'] / 'sweep'
    _cli(
        plugin,
        'sweep',
        str(plugin['bag']),
        '--backend',
        'brightness',
        '--param',
        'brightness.offset=0,2.5',
        '--out',
        str(out),
    )
    with (out / 'sweep.csv').open(newline='', encoding='utf-8') as file:
        rows = list(csv.DictReader(file))
    assert [(row['params'], row['brightness_error']) for row in rows] == [
        ('offset=0', '0.0'),
        ('offset=2.5', '2.5'),
    ]
