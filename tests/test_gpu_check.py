"""benchmarks/gpu_check.sh: the prepared GPU check, run here in its CPU mode (--dry-run).

One dry run (small inputs, no wheels, no network, no YOLOX-Nano) with the `backends` step made
to fail and the `versions` step made to outlast its limit: the archive is made, every step is
listed with its status, and the steps after the failing and the hanging one still run.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tarfile
import tomllib
from pathlib import Path
from typing import Any

import pytest

from benchmarks.gpu_check import ARCHIVE, ARCHIVE_LIMIT, ON_GPU_MACHINE, Config, main, plan

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / 'benchmarks' / 'gpu_check.sh'


@pytest.fixture(scope='module')
def dry_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    root = tmp_path_factory.mktemp('gpu-check')
    out, work, empty = root / 'out', root / 'work', root / 'empty'
    empty.mkdir()
    env = {**os.environ, 'PYTHON': sys.executable}
    args = [
        '--dry-run', '--out', str(out), '--work', str(work), '--wheels', str(empty),
        '--models', str(empty), '--fail', 'backends', '--hang', 'versions',
    ]  # fmt: skip
    done = subprocess.run(
        [str(SCRIPT), *args],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    steps = json.loads((out / 'steps.json').read_text(encoding='utf-8'))
    return {'done': done, 'out': out, 'work': work, 'steps': steps}


def _by_name(dry_run: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {step['name']: step for step in dry_run['steps']['steps']}


def test_the_dry_run_packs_its_logs_and_the_runs_json_and_csv_into_one_archive_under_16_mib(
    dry_run,
):
    assert dry_run['done'].returncode == 0, dry_run['done'].stderr
    archive = dry_run['out'] / ARCHIVE
    assert 0 < archive.stat().st_size <= ARCHIVE_LIMIT
    with tarfile.open(archive) as tar:
        names = set(tar.getnames())
    for name in ('check.log', 'steps.json', 'summary.json', 'summary.md'):
        assert f'gpu-check/{name}' in names
    for run in ('hsv', 'bundled-torch-fp32'):
        for name in ('run.json', 'summary.csv', 'frames.csv'):
            assert f'gpu-check/runs/{run}/{name}' in names
    assert 'gpu-check/peak/peak.json' in names
    assert not [name for name in names if name.endswith(('.mcap', '.html'))]
    # what comes back from a GPU machine: at most 8 files, here four, none in a folder
    returned = sorted(path.name for path in dry_run['out'].rglob('*'))
    assert returned == sorted([ARCHIVE, 'check.log', 'steps.json', 'summary.md'])


def test_every_step_is_listed_in_order_with_its_status_and_why_it_was_skipped(dry_run):
    config = Config(True, Path('o'), Path('w'), Path('x'), Path('m'), Path('s'), 'py', 1, '1x1', 1)
    assert [step['name'] for step in dry_run['steps']['steps']] == [
        step.name for step in plan(config)
    ]
    steps = _by_name(dry_run)
    assert steps['nvidia-smi']['status'] == 'skipped'
    assert steps['nvidia-smi']['reason'].startswith('dry run: needs a GPU')
    assert steps['install-wheels']['reason'] == 'dry run: uses this environment, not the wheels'
    for name in ('yolox-torch-fp16', 'yolox-torch-fp32', 'compare-yolox', 'yolox-ort-fp32'):
        assert steps[name]['status'] == 'skipped'
        assert 'yolox_nano.onnx not found' in steps[name]['reason']
    for name in (
        'inputs',
        'bundled-torch-fp32',
        'hsv',
        'stereo-cuda-torch',
        'compare-bundled',
        'peak-cuda',
        'seg-cuda-torch',
        'rig-cuda-shared',
        'rig-cuda-per-topic',
    ):
        assert steps[name]['status'] == 'ok', name
    assert steps['pytest-gpu']['status'] == 'ok'
    assert steps['summary']['status'] == 'ok'
    log = (dry_run['out'] / 'check.log').read_text(encoding='utf-8')
    assert '== [01] nvidia-smi: skipped (dry run: needs a GPU' in log
    counts = dry_run['steps']['counts']
    assert sum(counts.values()) == len(dry_run['steps']['steps'])


def test_a_failing_step_is_logged_with_its_exit_status_and_the_next_steps_still_run(dry_run):
    steps = _by_name(dry_run)
    assert steps['backends']['status'] == 'failed'
    assert steps['backends']['rc'] == 3
    assert steps['backends']['reason'] == '--fail'
    log = dry_run['work'] / 'gpu-check' / 'logs' / steps['backends']['log']
    assert 'failing on purpose' in log.read_text(encoding='utf-8')
    assert steps['inputs']['status'] == 'ok'
    assert '-- backends: failed (exit 3)' in dry_run['done'].stdout


def test_a_step_past_its_limit_is_killed_and_logged_as_a_timeout_and_the_next_steps_run(dry_run):
    steps = _by_name(dry_run)
    assert steps['versions']['status'] == 'timeout'
    assert steps['versions']['rc'] is None
    assert steps['versions']['seconds'] < 30
    assert steps['doctor']['status'] in ('ok', 'failed')  # it ran: 1 without a GPU
    assert steps['doctor']['rc'] is not None


def test_the_summary_holds_the_figures_read_from_the_run_folders(dry_run):
    summary = json.loads(
        (dry_run['work'] / 'gpu-check' / 'summary.json').read_text(encoding='utf-8')
    )
    runs = {run['run']: run for run in summary['runs']}
    hsv = runs['hsv']
    (topic,) = hsv['backends']['hsv']['topics'].values()
    assert topic['throughput_fps'] > 0
    assert topic['latency_ms_p50'] > 0
    (pair,) = hsv['agreement']
    assert (pair['backend_a'], pair['backend_b'], pair['n_b']) == ('hsv', 'null', 0)
    assert pair['n_a'] > 0
    assert runs['bundled-torch-fp32']['backends']['onnx_cpu']['name'] == 'onnx-cpu'
    # the stereo step's CPU counterpart: onnx-stereo alone, scored against the fixture's truth
    (stereo,) = runs['stereo-cuda-torch']['backends']['onnx_stereo']['topics'].values()
    assert 0 < stereo['epe'] < 5
    assert 0 <= stereo['bad2'] <= 1
    assert stereo['density'] == 1.0
    assert runs['stereo-cuda-torch']['stereo_agreement'] == []
    assert summary['peak']['backend'] == 'null'
    assert summary['peak']['peak_hz'] > 0


def test_on_a_gpu_machine_the_steps_install_the_wheels_offline_and_run_the_gpu_backends(tmp_path):
    wheels = tmp_path / 'whl'
    (wheels / 'models').mkdir(parents=True)
    (wheels / 'a-1-py3-none-any.whl').write_bytes(b'')
    (wheels / 'models' / 'yolox_nano.onnx').write_bytes(b'')
    config = Config(
        False,
        tmp_path,
        tmp_path,
        wheels,
        wheels / 'models',
        tmp_path / 'site',
        'py',
        300,
        '1920x1080',
        400,
    )
    steps = {step.name: step for step in plan(config)}
    install = steps['install-wheels'].argv
    assert '--no-index' in install
    assert install[-1] == str(wheels / 'a-1-py3-none-any.whl')
    fp16 = steps['yolox-torch-fp16']
    assert fp16.skip is None
    assert fp16.argv[fp16.argv.index('--precision') + 1] == 'fp16'
    assert {'onnx-cpu', 'cuda', 'torch', 'max'} <= set(fp16.argv)
    assert 'hsv-cuda' in steps['hsv'].argv
    assert '--rate' in steps['hsv'].argv
    assert 'cuda' in steps['peak-cuda'].argv
    stereo = steps['stereo-cuda-torch']
    assert {'onnx-stereo', 'cuda-stereo', 'torch', 'max'} <= set(stereo.argv)
    assert stereo.argv[stereo.argv.index('run') + 1].endswith('stereo.mcap')
    assert steps['ray-sweep-cell'].requires == 'ray'
    assert steps['inputs'].argv[-4:] == ('--frames', '300', '--size', '1920x1080')


def test_a_step_name_that_does_not_exist_is_refused_before_anything_runs(tmp_path, capsys):
    out, work = tmp_path / 'out', tmp_path / 'work'
    args = ['--dry-run', '--out', str(out), '--work', str(work), '--fail', 'no-such-step']
    assert main(args) == 2
    assert 'no step named no-such-step' in capsys.readouterr().err
    assert not out.exists()
    assert not work.exists()


def test_every_core_dependency_is_on_the_gpu_machine_or_a_pinned_wheel_of_make_gpu_wheels():
    makefile = (REPO / 'Makefile').read_text(encoding='utf-8')
    block = re.search(r'^GPU_WHEELS :=(.*?)\n\S', makefile, re.MULTILINE | re.DOTALL)
    assert block is not None
    pins = dict(pin.split('==') for pin in block.group(1).replace('\\', ' ').split())
    project = tomllib.loads((REPO / 'pyproject.toml').read_text(encoding='utf-8'))['project']
    for requirement in project['dependencies']:
        name = re.split(r'[<>=!~\[ ;]', requirement, maxsplit=1)[0].lower()
        assert name in ON_GPU_MACHINE or name in pins, name
    for name, version in pins.items():
        assert re.fullmatch(r'[0-9][0-9.]*', version), (name, version)
    assert 'onnx2torch' in pins
