"""Several instances of one backend in one run (``--backend LABEL=NAME``, ``--param
LABEL.KEY=VALUE``) through the command line: named by their labels in every output, each with
its own settings, compared with each other, in run and peak; bad input in one line, exit 2."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from replaybench.cli import app
from replaybench.fixtures.writer import write_mcap

REPO = Path(__file__).resolve().parents[1]
BUNDLED_MODEL = REPO / 'replaybench' / 'models' / 'blobs.onnx'
runner = CliRunner()


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fixture bag of the standard scene: 12 rgb8 frames with ground truth."""
    return write_mcap(tmp_path_factory.mktemp('bag') / 'scene.mcap', frames=12, size=(160, 120))


@pytest.fixture(scope='module')
def two_models(bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One run of the bundled detector under two labels, the second from a copy of the model
    file on one thread, each replayed twice (--repeat 2)."""
    folder = tmp_path_factory.mktemp('runs')
    model = shutil.copy(BUNDLED_MODEL, folder / 'second.onnx')
    out = folder / 'run'
    result = runner.invoke(
        app,
        [
            'run',
            str(bag),
            '--backend',
            'fp32=onnx-cpu',
            '--backend',
            'int8=onnx-cpu',
            '--param',
            f'int8.model={model}',
            '--param',
            'int8.threads=1',
            '--repeat',
            '2',
            '--out',
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    (out / 'stdout.txt').write_text(result.stdout, encoding='utf-8')
    return out


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as f:
        return list(csv.DictReader(f))


def test_each_instance_is_named_by_its_label_in_the_terminal_and_the_csvs(
    two_models: Path,
) -> None:
    table = (two_models / 'stdout.txt').read_text(encoding='utf-8').splitlines()
    assert [line.split()[0] for line in table[:3]] == ['backend', 'fp32', 'int8']
    assert [r['backend'] for r in _csv(two_models / 'summary.csv')] == ['fp32', 'int8']
    frames = _csv(two_models / 'frames.csv')
    assert {r['backend'] for r in frames} == {'fp32', 'int8'}
    # interleaved as two backends are: fp32's pass, int8's, then the second of each
    passes = list(dict.fromkeys((r['backend'], r['repeat']) for r in frames))
    assert passes == [('fp32', '0'), ('int8', '0'), ('fp32', '1'), ('int8', '1')]


def test_run_json_records_each_instances_backend_and_its_own_params(two_models: Path) -> None:
    run = json.loads((two_models / 'run.json').read_text(encoding='utf-8'))
    entries = {b['name']: b for b in run['backends']}
    assert list(entries) == ['fp32', 'int8']
    assert [(b['label'], b['backend']) for b in entries.values()] == [
        ('fp32', 'onnx-cpu'),
        ('int8', 'onnx-cpu'),
    ]
    assert entries['fp32']['params'] == {}
    second = str(two_models.parent / 'second.onnx')
    assert entries['int8']['params'] == {'model': second, 'threads': '1'}
    # the settings reached that instance alone
    assert Path(entries['int8']['info']['model']) == Path(second)
    assert Path(entries['fp32']['info']['model']) == BUNDLED_MODEL
    assert (entries['int8']['info']['threads'], entries['int8']['info']['intra_op_threads']) == (
        1,
        1,
    )
    assert entries['fp32']['info']['threads'] is None  # the run's default, not int8's
    assert [s['backend'] for s in run['summary']] == ['fp32', 'int8']


def test_outputs_mcap_and_the_report_name_each_instance_by_its_label(two_models: Path) -> None:
    from mcap.reader import make_reader

    with (two_models / 'outputs.mcap').open('rb') as f:
        topics = {c.topic for _, c, _ in make_reader(f).iter_messages()}
    ours = sorted(t for t in topics if t.startswith('/replaybench/'))
    assert ours == [
        '/replaybench/fp32/camera/image_raw/detections',
        '/replaybench/int8/camera/image_raw/detections',
    ]
    html = (two_models / 'report.html').read_text(encoding='utf-8')
    for label in ('fp32', 'int8'):  # the summary table's rows and the per-backend sections
        assert f'</span>{label}</td>' in html
        assert f'<h3>{label} · <code>/camera/image_raw</code></h3>' in html
    second = two_models.parent / 'second.onnx'
    assert (
        f'<dt>backends</dt><dd>fp32 (onnx-cpu), int8 (onnx-cpu model={second} threads=1)</dd>'
        in html
    )


def test_compare_with_a_baseline_backend_compares_the_instances_of_one_run(
    two_models: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'cmp'
    result = runner.invoke(
        app, ['compare', str(two_models), '--baseline-backend', 'fp32', '--out', str(out)]
    )
    assert result.exit_code == 0, result.output
    assert 'baseline' in result.stdout
    assert '(backend fp32)' in result.stdout
    assert '· int8 · /camera/image_raw vs fp32' in result.stdout
    rows = {r['backend']: r for r in _csv(out / 'comparison.csv')}
    assert set(rows) == {'fp32', 'int8'}
    assert rows['int8']['baseline_backend'] == 'fp32'


def test_a_param_changes_its_instance_alone(bag: Path, tmp_path: Path) -> None:
    out = tmp_path / 'run'
    result = runner.invoke(
        app,
        [
            'run',
            str(bag),
            '-b',
            'small=hsv',
            '-b',
            'big=hsv',
            '--param',
            'big.min_area=100000',
            '--out',
            str(out),
            '--no-report',
        ],
    )
    assert result.exit_code == 0, result.output
    run = json.loads((out / 'run.json').read_text(encoding='utf-8'))
    areas = {b['name']: b['info']['detector']['min_area'] for b in run['backends']}
    assert areas['big'] == 100000.0
    assert areas['small'] < 1000
    per_frame = {s['backend']: s['detections_per_frame'] for s in run['summary']}
    assert per_frame['small'] > 0
    assert per_frame['big'] == 0


def test_each_per_topic_pipeline_of_an_instance_has_its_params(tmp_path: Path) -> None:
    bag = write_mcap(tmp_path / 'two.mcap', frames=4, size=(160, 120), cameras=2)
    out = tmp_path / 'run'
    result = runner.invoke(
        app,
        [
            'run',
            str(bag),
            '-b',
            'small=hsv',
            '-b',
            'big=hsv',
            '--param',
            'big.min_area=100000',
            '--pipelines',
            'per-topic',
            '--out',
            str(out),
            '--no-report',
        ],
    )
    assert result.exit_code == 0, result.output
    rows = [(r['backend'], r['topic']) for r in _csv(out / 'summary.csv')]
    cameras = sorted({t for _, t in rows if t != 'rig'})
    assert len(cameras) == 2
    per_frame = {
        (r['backend'], r['topic']): float(r['detections_per_frame'])
        for r in _csv(out / 'summary.csv')
    }
    for camera in cameras:  # the second camera's pipeline is an instance made for it
        assert per_frame['small', camera] > 0
        assert per_frame['big', camera] == 0


def test_a_backend_given_by_its_name_keeps_its_name_and_takes_params(
    bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'run'
    result = runner.invoke(
        app,
        [
            'run',
            str(bag),
            '-b',
            'onnx-cpu',
            '--param',
            'onnx-cpu.max_det=1',
            '--out',
            str(out),
            '--no-report',
        ],
    )
    assert result.exit_code == 0, result.output
    run = json.loads((out / 'run.json').read_text(encoding='utf-8'))
    (entry,) = run['backends']
    assert (entry['name'], entry['label'], entry['backend']) == ('onnx-cpu', 'onnx_cpu', 'onnx-cpu')
    assert entry['params'] == {'max_det': '1'}
    assert run['summary'][0]['detections_per_frame'] <= 1


def test_peak_searches_an_instance_under_its_label_with_its_params(
    bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'peak'
    result = runner.invoke(
        app,
        [
            'peak',
            str(bag),
            '--backend',
            'one=onnx-cpu',
            '--param',
            'one.threads=1',
            '--trial-frames',
            '6',
            '--max-hz',
            '40',
            '--refine-steps',
            '0',
            '--out',
            str(out),
            '--no-report',
        ],
    )
    assert result.exit_code == 0, result.output
    assert 'one: peak sustainable rate' in result.stdout
    assert json.loads((out / 'peak.json').read_text(encoding='utf-8'))['backend'] == 'one'
    trial = json.loads((out / 'trials' / 'max' / 'run.json').read_text(encoding='utf-8'))
    (entry,) = trial['backends']
    assert (entry['name'], entry['backend'], entry['params']) == (
        'one',
        'onnx-cpu',
        {'threads': '1'},
    )
    assert entry['info']['threads'] == 1


@pytest.mark.parametrize(
    ('args', 'said'),
    [
        (
            ['-b', 'a=hsv', '-b', 'a=null'],
            "two --backend instances have the label 'a'",
        ),
        (['-b', 'hsv', '-b', 'hsv'], "two --backend instances have the label 'hsv'"),
        (
            ['-b', 'x-1=hsv', '-b', 'x_1=null'],
            "two --backend instances have the labels 'x-1' and 'x_1' (written 'x_1'",
        ),
        (['-b', 'det+trk=hsv'], "label 'det+trk': a label is letters, digits, '_' and '-' only"),
        (['-b', 'a.b=hsv'], "(no '+', '=' or '.')"),
        (['-b', '=hsv'], 'an empty label'),
        (['-b', 'a='], 'no backend name after ='),
        (['-b', 'a=hsv', '--param', 'b.min_area=5'], "no --backend instance is labelled 'b'"),
        (['-b', 'a=hsv', '--param', 'a.min_area'], "invalid --param 'a.min_area': use LABEL"),
        (['-b', 'a=hsv', '--param', 'a.colour=red'], "hsv: unknown option 'colour'"),
        (['-b', 'a=onnx-cpu', '--param', 'a.modle=x.onnx'], "onnx-cpu: unknown option 'modle'"),
        (['-b', 'a=null', '--param', 'a.min_area=5'], "null: unknown option 'min_area'"),
        (['-b', 'a=busy', '--param', 'a.ms=5'], "busy backend: unknown option 'ms'"),
        (['-b', 'a=hsv', '--param', 'a.min_area=big'], "option min_area='big' is not a number"),
        (['-b', 'a=onnx-cpu', '--param', 'a.conf=high'], "--param a.conf='high': expected a"),
        (['-b', 'a=onnx-cpu', '--param', 'a.threads=0'], 'expected an integer >= 1'),
        (['-b', 'a=hsv', '--param', 'a.min_area=1,2'], 'one value per instance in a run'),
        (
            ['-b', 'a=hsv', '--param', 'a.min_area=1', '--param', 'a.min_area=2'],
            '--param a.min_area is given twice',
        ),
        (['-b', 'a=nosuch'], "unknown backend 'nosuch'"),
    ],
)
def test_bad_instances_and_params_exit_2_with_one_line_and_write_nothing(
    bag: Path, tmp_path: Path, args: list[str], said: str
) -> None:
    out = tmp_path / 'run'
    result = runner.invoke(app, ['run', str(bag), *args, '--out', str(out)])
    assert result.exit_code == 2, result.output
    assert 'Traceback' not in result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith('replaybench: error: ')
    assert said in line
    assert not out.exists()


def test_the_python_api_takes_instances_as_the_command_line_does(bag: Path) -> None:
    import replaybench.api as rb

    res = rb.run(
        bag,
        backends=['small=hsv', 'big=hsv'],
        params=['big.min_area=100000'],
        max_frames=4,
    )
    assert [(b.name, b.backend, dict(b.params)) for b in res.backends] == [
        ('small', 'hsv', {}),
        ('big', 'hsv', {'min_area': '100000'}),
    ]
    assert [s.backend for s in res.summary_rows] == ['small', 'big']
