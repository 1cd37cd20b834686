"""Sweeps on one local Ray instance (started once for the module): the cells, their run
folders, byte identity with standalone runs, failed cells, resume and --param grids."""

from __future__ import annotations

import csv
import itertools
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from replaybench.app.sweep import SweepProgress, SweepResult

pytestmark = pytest.mark.usefixtures('ray_local')

REPO = Path(__file__).resolve().parents[2]
SCHEMA = REPO / 'replaybench' / 'schemas' / 'sweep.schema.json'
RUN_FILES = {'outputs.mcap', 'frames.csv', 'summary.csv', 'run.json', 'report.html'}


def _sweep(inputs: list[Path], out: Path, **options: Any) -> SweepResult:
    from replaybench.app.sweep import sweep

    options.setdefault('max_frames', 30)
    return sweep(inputs, out=out, command=['replaybench', 'sweep'], **options)


def _valid(record: dict[str, Any]) -> None:
    import jsonschema

    schema = json.loads(SCHEMA.read_text(encoding='utf-8'))
    jsonschema.Draft202012Validator(schema, format_checker=jsonschema.FormatChecker()).validate(
        record
    )


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as f:
        return list(csv.DictReader(f))


def test_a_local_sweep_of_two_bags_and_two_backends_writes_four_run_folders_and_the_matrix(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    seen: list[SweepProgress] = []
    result = _sweep(
        [bags['a'], bags['b']], tmp_path / 'sw', backends=['hsv', 'null'], progress=seen.append
    )
    assert result.status == 'complete'
    assert result.exit_code == 0
    record = json.loads((tmp_path / 'sw' / 'sweep.json').read_text(encoding='utf-8'))
    _valid(record)
    assert record == result.record
    assert record['counts'] == {
        'cells': 4,
        'complete': 4,
        'failed': 0,
        'interrupted': 0,
        'pending': 0,
        'resumed': 0,
    }
    engine = record['engine']
    import ray

    assert engine['ray_version'] == ray.__version__
    assert engine['resources']['CPU'] == 2.0
    assert engine['resources']['replaybench_timed_slot'] == 1.0
    assert engine['head_node_id'] == engine['nodes'][0]['node_id']
    cells = record['cells']
    assert [(c['input'], c['backend']) for c in cells] == [
        (str(bags['a']), 'hsv'),
        (str(bags['a']), 'null'),
        (str(bags['b']), 'hsv'),
        (str(bags['b']), 'null'),
    ]
    for cell in cells:
        folder = tmp_path / 'sw' / cell['run_dir']
        assert {p.name for p in folder.iterdir()} >= RUN_FILES
        run = json.loads((folder / 'run.json').read_text(encoding='utf-8'))
        assert run['status'] == 'complete'
        assert run['backends'][0]['name'] == cell['backend']
        assert run['sweep']['key'] == cell['key']
        assert run['sweep']['node_id'] == engine['head_node_id']
        assert run['sweep']['placement'] == 'node-slot'
        # one node slot: the cells ran one after another
        assert run['sweep']['concurrency'] == {'limit_per_node': 1, 'max_cells_on_node': 1}
        metrics = cell['metrics']
        summary = run['summary'][0]
        assert metrics['frames'] == summary['measured'] == 27
        assert metrics['fps'] == pytest.approx(summary['throughput_fps'])
        assert metrics['p50_ms'] == pytest.approx(summary['latency_ms_p50'])
        assert metrics['p99_ms'] == pytest.approx(summary['latency_ms_p99'])
        low, high = metrics['p50_ci']
        assert low <= metrics['p50_ms'] <= high
        low, high = metrics['fps_ci']
        assert 0 < low < high
    starts = sorted((c['started_at'], c['finished_at']) for c in cells)
    assert all(a[1] <= b[0] for a, b in itertools.pairwise(starts))
    rows = _csv(tmp_path / 'sw' / 'sweep.csv')
    assert [r['cell'] for r in rows] == [c['cell'] for c in cells]
    assert {r['status'] for r in rows} == {'complete'}
    assert float(rows[0]['p99_low']) <= float(rows[0]['p99_ms']) <= float(rows[0]['p99_high'])
    frame = result.cells
    assert list(frame['cell']) == [c['cell'] for c in cells]
    assert frame['fps'].tolist() == pytest.approx([c['metrics']['fps'] for c in cells])
    html = (tmp_path / 'sw' / 'sweep.html').read_text(encoding='utf-8')
    for cell in cells:
        assert f'href="{cell["run_dir"]}/report.html"' in html
    assert html.count('best FPS') == 2  # one per input row
    assert f'Ray {ray.__version__}' in html
    assert seen
    assert seen[-1].done == seen[-1].total == 4
    assert seen[-1].running == seen[-1].failed == 0


def test_a_cell_writes_the_same_outputs_mcap_as_a_standalone_run(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    result = _sweep([bags['a']], tmp_path / 'sw', backends=['hsv', 'onnx-cpu'], max_frames=12)
    assert result.status == 'complete', result.record['cells']
    for cell in result.record['cells']:
        alone = tmp_path / f'alone-{cell["backend"]}'
        proc = subprocess.run(
            [
                sys.executable,
                '-m',
                'replaybench',
                'run',
                str(bags['a']),
                '--backend',
                cell['backend'],
                '--max-frames',
                '12',
                '--out',
                str(alone),
            ],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        assert proc.returncode == 0, proc.stderr
        mine = (tmp_path / 'sw' / cell['run_dir'] / 'outputs.mcap').read_bytes()
        assert mine == (alone / 'outputs.mcap').read_bytes()
        theirs = json.loads((alone / 'run.json').read_text(encoding='utf-8'))
        run = json.loads(
            (tmp_path / 'sw' / cell['run_dir'] / 'run.json').read_text(encoding='utf-8')
        )
        assert run['settings'] == theirs['settings']
        assert run['inputs'][0]['sha256'] == theirs['inputs'][0]['sha256']


def test_a_corrupt_input_fails_its_cells_with_one_line_while_the_others_finish(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    result = _sweep([bags['a'], bags['corrupt']], tmp_path / 'sw', backends=['null', 'cuda'])
    assert result.status == 'failed'
    assert result.exit_code == 1
    by = {(Path(c['input']).name, c['backend']): c for c in result.record['cells']}
    good = by['a.mcap', 'null']
    assert good['status'] == 'complete'
    bad = by['corrupt.mcap', 'null']
    assert bad['status'] == 'failed'
    assert bad['error'].startswith(f'{bags["corrupt"].resolve()}: ')
    assert '\n' not in bad['error']
    assert bad['run_dir'] is None
    assert not (tmp_path / 'sw' / 'cells' / bad['cell']).exists()
    # a GPU cell in a cluster without GPUs fails at once, without waiting for a GPU
    for name in ('a.mcap', 'corrupt.mcap'):
        assert by[name, 'cuda']['status'] == 'failed'
        assert by[name, 'cuda']['error'] == 'no GPU in the Ray cluster for this GPU backend'
        assert by[name, 'cuda']['placement'] == 'gpu'
    rows = {(Path(r['input']).name, r['backend']): r for r in _csv(tmp_path / 'sw' / 'sweep.csv')}
    assert rows['corrupt.mcap', 'null']['error'] == bad['error']
    assert rows['corrupt.mcap', 'null']['fps'] == ''
    _valid(result.record)
    html = (tmp_path / 'sw' / 'sweep.html').read_text(encoding='utf-8')
    assert '3 cell(s) failed' in html


def _stamp(folder: Path) -> dict[str, tuple[int, bytes]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_mtime_ns, p.read_bytes())
        for p in folder.rglob('*')
        if p.is_file()
    }


def test_running_the_same_sweep_again_keeps_complete_cells_and_reruns_failed_ones(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    broken = tmp_path / 'c.mcap'
    shutil.copyfile(bags['corrupt'], broken)
    inputs = [bags['a'], broken]
    out = tmp_path / 'sw'
    first = _sweep(inputs, out, backends=['hsv'])
    assert [c['status'] for c in first.record['cells']] == ['complete', 'failed']
    kept = first.record['cells'][0]
    before = _stamp(out / kept['run_dir'])

    second = _sweep(inputs, out, backends=['hsv'])
    assert second.status == 'failed'
    assert [c['status'] for c in second.record['cells']] == ['complete', 'failed']
    assert second.record['cells'][0]['resumed'] is True
    assert second.record['cells'][1]['resumed'] is False
    assert second.record['counts']['resumed'] == 1
    assert _stamp(out / kept['run_dir']) == before
    assert second.record['cells'][0]['metrics'] == kept['metrics']

    shutil.copyfile(bags['b'], broken)  # the input is repaired: a new cell key
    third = _sweep(inputs, out, backends=['hsv'])
    assert third.status == 'complete'
    assert [c['resumed'] for c in third.record['cells']] == [True, False]
    assert _stamp(out / kept['run_dir']) == before
    assert third.record['cells'][1]['key'] != second.record['cells'][1]['key']
    assert (out / third.record['cells'][1]['run_dir'] / 'run.json').is_file()
    # a sweep with nothing left to run starts no Ray at all and keeps the engine record
    fourth = _sweep(inputs, out, backends=['hsv'])
    assert fourth.record['counts']['resumed'] == 2
    assert fourth.record['engine'] == third.record['engine']


def test_a_param_grid_runs_one_cell_per_value_with_that_value(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    result = _sweep(
        [bags['a']],
        tmp_path / 'sw',
        backends=['hsv', 'null'],
        params=['hsv.min_area=10,100000'],
        max_frames=12,
    )
    assert result.status == 'complete'
    cells = result.record['cells']
    assert [(c['backend'], c['params']) for c in cells] == [
        ('hsv', {'min_area': '10'}),
        ('hsv', {'min_area': '100000'}),
        ('null', {}),
    ]
    detections = []
    for cell in cells[:2]:
        run = json.loads((tmp_path / 'sw' / cell['run_dir'] / 'run.json').read_text())
        assert run['backends'][0]['info']['detector']['min_area'] == float(
            cell['params']['min_area']
        )
        assert run['sweep']['params'] == cell['params']
        detections.append(run['summary'][0]['detections_per_frame'])
    assert detections[0] > 0
    assert detections[1] == 0  # no blob of the small frames is that large
    assert list(result.cells['params']) == ['min_area=10', 'min_area=100000', '']
    html = (tmp_path / 'sw' / 'sweep.html').read_text(encoding='utf-8')
    assert 'hsv min_area=10</th>' in html
    assert 'hsv min_area=100000</th>' in html


def test_packed_cells_are_flagged_as_not_comparable(bags: dict[str, Path], tmp_path: Path) -> None:
    result = _sweep([bags['a'], bags['b']], tmp_path / 'sw', backends=['null'], pack=True)
    assert result.status == 'complete'
    for cell in result.record['cells']:
        assert cell['placement'] == 'packed'
        assert 'packed placement: timings not comparable' in cell['flags']
        assert cell['concurrency']['limit_per_node'] is None
    assert result.record['engine']['placement']['cpu_cells'] == 'packed, one per CPU'
    assert 'measured under different conditions' in (tmp_path / 'sw' / 'sweep.html').read_text()


def _workers(title: bytes) -> list[int]:
    found = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmdline = (proc / 'cmdline').read_bytes()
        except OSError:
            continue
        if cmdline.startswith(title):
            found.append(int(proc.name))
    return found


@pytest.mark.skipif(not Path('/proc/self/cmdline').exists(), reason='needs /proc')
def test_a_cell_whose_worker_is_killed_is_run_again_by_ray_and_completes(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    import signal
    import threading
    import time

    from replaybench.app.options import RunOptions
    from replaybench.app.sweep import input_identity, parse_params, plan_cells

    params = ['busy.busy_ms=97']
    settings = RunOptions(max_frames=30)
    cell = plan_cells(
        [input_identity(bags['a'])], ['busy'], parse_params(params, ['busy']), settings
    )[0]
    title = f'ray::replaybench cell {cell.name}'.encode()
    results: list[SweepResult] = []
    runner = threading.Thread(
        target=lambda: results.append(
            _sweep([bags['a']], tmp_path / 'sw', backends=['busy'], params=params)
        )
    )
    runner.start()
    killed = None
    deadline = time.monotonic() + 120
    while killed is None and time.monotonic() < deadline and runner.is_alive():
        found = _workers(title)
        if found:
            killed = found[0]
            os.kill(killed, signal.SIGKILL)
        time.sleep(0.05)
    runner.join(timeout=300)
    assert killed is not None, 'the cell never ran'
    assert results, 'the sweep did not return'
    result = results[0]
    assert result.status == 'complete', result.record['cells']
    entry = result.record['cells'][0]
    assert entry['key'] == cell.key
    run = json.loads((tmp_path / 'sw' / entry['run_dir'] / 'run.json').read_text())
    assert run['status'] == 'complete'
    assert run['summary'][0]['measured'] == 27


def test_a_cell_measured_on_another_cpu_is_flagged(bags: dict[str, Path], tmp_path: Path) -> None:
    from replaybench.results.atomic import write_json_atomic

    inputs = [bags['a'], bags['b'], REPO / 'fixtures' / 'bags' / 'jpeg.mcap']
    out = tmp_path / 'sw'
    first = _sweep(inputs, out, backends=['null'])
    assert [c['flags'] for c in first.record['cells']] == [[], [], []]
    # the second cell as if an earlier invocation had run it on a node of another kind
    path = out / first.record['cells'][1]['run_dir'] / 'run.json'
    run = json.loads(path.read_text(encoding='utf-8'))
    usual = first.record['cells'][0]['conditions']['cpu']
    run['environment']['cpu']['model'] = 'Other CPU 9000'
    write_json_atomic(path, run)
    again = _sweep(inputs, out, backends=['null'])
    assert again.record['counts']['resumed'] == 3
    flags = [c['flags'] for c in again.record['cells']]
    cores = run['environment']['cpu']['logical_cores']
    assert flags == [[], [f'other CPU: Other CPU 9000 x{cores} (most cells: {usual})'], []]
    assert again.cells['flags'].tolist() == ['', flags[1][0], '']
    html = (out / 'sweep.html').read_text(encoding='utf-8')
    assert '1 cell(s) measured under different conditions' in html


def test_a_stereo_sweep_sets_the_matchers_disparities_and_shows_its_figures(
    tmp_path: Path,
) -> None:
    from replaybench.fixtures.stereo import write_stereo_mcap
    from replaybench.stereo import DisparityCounts, Matcher, score_disparity

    bag = write_stereo_mcap(tmp_path / 'stereo.mcap', 3)
    result = _sweep([bag], tmp_path / 'sw', backends=['sgbm'], params=['sgbm.disparities=32,64'])
    assert result.status == 'complete'
    rows = _csv(tmp_path / 'sw' / 'sweep.csv')
    assert [r['params'] for r in rows] == ['disparities=32', 'disparities=64']
    from replaybench.fixtures.stereo import render_stereo

    for row, cell in zip(rows, result.record['cells'], strict=True):
        run = json.loads((tmp_path / 'sw' / cell['run_dir'] / 'run.json').read_text())
        wanted = int(cell['params']['disparities'])
        assert run['backends'][0]['info']['parameters']['disparity_range'] == wanted
        # the cell's figures are the bare matcher's at that range on the same pairs
        matcher = Matcher.from_mapping('sgbm', {'disparities': wanted})
        total = DisparityCounts()
        for i in range(3):
            view = render_stereo((320, 240), i)
            total += score_disparity(matcher.compute(view.left, view.right), view.disparity)
        figures = total.figures()
        assert float(row['bad2']) == pytest.approx(figures.bad2, abs=1e-9)
        assert float(row['epe']) == pytest.approx(figures.epe, abs=1e-9)
        assert row['map50'] == ''
    assert rows[0]['bad2'] != rows[1]['bad2']


def test_labelled_instances_of_one_backend_sweep_their_axes_with_their_fixed_params(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    result = _sweep(
        [bags['a']],
        tmp_path / 'sw',
        backends=['small=hsv', 'big=hsv'],
        params=['small.min_area=10', 'big.min_area=100000', 'big.kernel=3,5'],
        max_frames=12,
    )
    assert result.status == 'complete'
    cells = result.record['cells']
    assert [(c['backend'], c['params']) for c in cells] == [
        ('small', {'min_area': '10'}),
        ('big', {'min_area': '100000', 'kernel': '3'}),
        ('big', {'min_area': '100000', 'kernel': '5'}),
    ]
    assert result.record['settings']['backends'] == ['small=hsv', 'big=hsv']
    detections = []
    for cell in cells:
        run = json.loads((tmp_path / 'sw' / cell['run_dir'] / 'run.json').read_text())
        (entry,) = run['backends']
        assert (entry['name'], entry['backend'], entry['params']) == (
            cell['backend'],
            'hsv',
            cell['params'],
        )
        assert entry['info']['detector']['min_area'] == float(cell['params']['min_area'])
        assert run['summary'][0]['backend'] == cell['backend']
        detections.append(run['summary'][0]['detections_per_frame'])
    assert detections[0] > 0
    assert detections[1:] == [0, 0]
    _valid(result.record)
