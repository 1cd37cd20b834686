"""The Python API (``import replaybench as rb``) end to end, on the bundled fixture bags."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
from pandas.testing import assert_frame_equal
from typer.testing import CliRunner

import replaybench as rb
from replaybench.errors import UsageError
from replaybench.results.io import read_peak_result
from replaybench.results.records import FRAMES_CSV_COLUMNS
from replaybench.results.stats import SUMMARY_CSV_COLUMNS
from replaybench.results.tables import FRAMES_DTYPES, SUMMARY_DTYPES, read_summary_csv

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / 'fixtures' / 'bags' / 'jpeg.mcap'
TWO_CAMERAS = REPO / 'fixtures' / 'bags' / 'two_camera.mcap'

#: frames.csv columns that hold no measured time: equal between any two runs of one bag
FIXED_COLUMNS = [
    'input',
    'backend',
    'topic',
    'seq',
    'log_time_ns',
    'stamp_ns',
    'status',
    'note',
    'warmup',
    'dropped',
    'detections',
]
#: summary.csv columns that hold no measured time
FIXED_SUMMARY = [
    'backend',
    'topic',
    'frames',
    'processed',
    'measured',
    'warmup',
    'dropped',
    'skipped',
    'detections_per_frame',
    'precision50',
    'recall50',
    'map50',
    'map50_95',
]


def _read_frames_csv_with_pandas(path: Path) -> pd.DataFrame:
    """frames.csv read by pandas itself, with the API's column types."""
    return pd.read_csv(
        path,
        dtype={k: v for k, v in FRAMES_DTYPES.items() if v != 'bool'},
        keep_default_na=False,
        na_values={k: [''] for k, v in FRAMES_DTYPES.items() if v != 'str'},
        true_values=['1'],
        false_values=['0'],
    ).astype({k: 'bool' for k, v in FRAMES_DTYPES.items() if v == 'bool'})


def test_importing_replaybench_loads_no_heavy_module():
    code = (
        'import sys, replaybench\n'
        "heavy = ['pandas', 'numpy', 'cv2', 'onnxruntime', 'ray', 'mcap', 'typer']\n"
        'print([m for m in heavy if m in sys.modules])\n'
        'print(sorted(set(replaybench.__all__) - set(dir(replaybench))))'
    )
    out = subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert out == ['[]', '[]']


def test_the_api_names_load_on_first_use():
    assert rb.run.__module__ == 'replaybench.api'
    assert rb.RunResult.__name__ == 'RunResult'
    assert set(rb.__all__) >= {'run', 'load_run', 'compare', 'peak', 'sweep', 'RunResult'}
    with pytest.raises(AttributeError, match='no attribute'):
        _ = rb.nothing_by_this_name


def test_an_api_run_and_a_cli_run_of_one_bag_give_equal_frames_and_identical_detections(
    tmp_path,
):
    api = tmp_path / 'api'
    cli = tmp_path / 'cli'
    res = rb.run(TWO_CAMERAS, backends=['hsv', 'null'], out=api)
    command = ['run', str(TWO_CAMERAS), '--backend', 'hsv', '--backend', 'null', '--out', str(cli)]
    subprocess.run(
        [sys.executable, '-m', 'replaybench', *command],
        capture_output=True,
        check=True,
    )
    assert sorted(p.name for p in api.iterdir()) == sorted(p.name for p in cli.iterdir())
    frames_api = _read_frames_csv_with_pandas(api / 'frames.csv')
    frames_cli = _read_frames_csv_with_pandas(cli / 'frames.csv')
    assert len(frames_api) == 40  # 2 backends x 2 topics x 10 frames
    assert_frame_equal(frames_api[FIXED_COLUMNS], frames_cli[FIXED_COLUMNS])
    assert (api / 'outputs.mcap').read_bytes() == (cli / 'outputs.mcap').read_bytes()
    assert res.status == 'complete'


def test_the_result_tables_hold_exactly_what_the_csv_files_hold(tmp_path):
    out = tmp_path / 'run'
    res = rb.run(BAG, backends=('hsv', 'null'), out=out)
    assert list(res.frames.columns) == list(FRAMES_CSV_COLUMNS)
    assert dict(res.frames.dtypes.astype(str)) == FRAMES_DTYPES
    # after the known columns, the streaming scores: empty, refused at --rate max
    streaming = ['streaming_map50', 'streaming_map50_95', 'streaming_recall', 'streaming_precision']
    assert list(res.summary.columns) == [*SUMMARY_CSV_COLUMNS, *streaming]
    dtypes = dict(res.summary.dtypes.astype(str))
    assert {k: dtypes[k] for k in SUMMARY_CSV_COLUMNS} == SUMMARY_DTYPES
    assert {dtypes[k] for k in streaming} == {'float64'}
    assert res.summary[streaming].isna().all().all()
    assert_frame_equal(res.frames, _read_frames_csv_with_pandas(out / 'frames.csv'))
    assert_frame_equal(res.summary, read_summary_csv(out / 'summary.csv'))
    # typed attributes, not dicts
    assert res.settings.rate == 'max'
    assert res.inputs[0].sha256 is not None
    assert len(res.inputs[0].sha256) == 64
    assert [b.name for b in res.backends] == ['hsv', 'null']


def test_load_run_returns_a_result_equal_to_the_one_the_run_returned(tmp_path):
    out = tmp_path / 'run'
    res = rb.run(BAG, backends='hsv', out=out)
    loaded = rb.load_run(out)
    assert loaded == res
    assert_frame_equal(loaded.frames, res.frames, check_dtype=True)
    assert_frame_equal(loaded.summary, res.summary, check_dtype=True)


def test_a_run_without_out_writes_nothing_and_matches_a_run_with_a_folder(tmp_path, monkeypatch):
    work = tmp_path / 'cwd'
    work.mkdir()
    monkeypatch.chdir(work)
    in_memory = rb.run(BAG, backends=['hsv', 'null'])
    assert list(work.iterdir()) == []
    assert list(tmp_path.iterdir()) == [work]
    assert in_memory.status == 'complete'
    on_disk = rb.run(BAG, backends=['hsv', 'null'], out=tmp_path / 'run')
    assert_frame_equal(in_memory.frames[FIXED_COLUMNS], on_disk.frames[FIXED_COLUMNS])
    assert_frame_equal(in_memory.summary[FIXED_SUMMARY], on_disk.summary[FIXED_SUMMARY])
    # a run kept in memory names no file; the folder's run names its own
    assert in_memory.outputs is None
    assert on_disk.outputs is not None
    assert on_disk.outputs.frames_csv == 'frames.csv'
    assert on_disk.outputs.report == 'report.html'
    assert on_disk.outputs.samples


def test_repeated_calls_give_identical_results():
    first = rb.run(TWO_CAMERAS, backends=['hsv', 'null'])
    second = rb.run(TWO_CAMERAS, backends=['hsv', 'null'])
    assert_frame_equal(first.frames[FIXED_COLUMNS], second.frames[FIXED_COLUMNS])
    assert_frame_equal(first.summary[FIXED_SUMMARY], second.summary[FIXED_SUMMARY])
    # the bag has ground truth: each camera scored (the rig row, both cameras, keeps none)
    cameras = first.summary[first.summary['topic'] != 'rig']
    assert cameras['map50'].notna().all()
    assert list(first.summary['topic']).count('rig') == 2
    assert [i.sha256 for i in first.inputs] == [i.sha256 for i in second.inputs]
    assert first.agreement == second.agreement


def test_a_library_run_leaves_the_process_as_it_found_it(capfd):
    import cv2
    from threadpoolctl import threadpool_info

    def limits() -> list[tuple[str, int]]:
        return sorted((i['filepath'], i['num_threads']) for i in threadpool_info())

    environ = dict(os.environ)
    argv = list(sys.argv)
    cv2_threads = cv2.getNumThreads()
    pools = limits()
    live = set(threading.enumerate())
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    during: list[tuple[object, object, int, list[int]]] = []

    def progress(_done: int, _total: int) -> None:
        during.append(
            (
                signal.getsignal(signal.SIGINT),
                signal.getsignal(signal.SIGTERM),
                cv2.getNumThreads(),
                [n for _, n in limits()],
            )
        )

    res = rb.run(BAG, backends=['hsv', 'onnx-cpu'], threads=1, progress=progress)
    assert res.settings.threads == 1
    assert during
    # while frames replay: no handler installed, the thread limits in force
    for sigint, sigterm, threads, pool_threads in during:
        assert (sigint, sigterm) == (handlers[signal.SIGINT], handlers[signal.SIGTERM])
        assert threads == 1
        assert set(pool_threads) <= {1}
    assert dict(os.environ) == environ
    assert sys.argv == argv
    assert cv2.getNumThreads() == cv2_threads
    assert limits() == pools
    assert set(threading.enumerate()) == live
    assert {s: signal.getsignal(s) for s in handlers} == handlers
    assert capfd.readouterr() == ('', '')
    assert res.command == ()  # run.json records no host program's sys.argv


def test_a_stop_token_set_during_the_replay_ends_the_run_as_interrupted():
    stop = threading.Event()

    def progress(done: int, _total: int) -> None:
        if done >= 3:
            stop.set()

    res = rb.run(TWO_CAMERAS, backends=['null'], rate='recorded', progress=progress, stop=stop)
    assert res.status == 'interrupted'
    assert 3 <= len(res.frames) < 20


def test_bad_options_are_refused_naming_the_option():
    with pytest.raises(UsageError, match='--queue-depth must be at least 1'):
        rb.run(BAG, queue_depth=0)
    with pytest.raises(UsageError, match='invalid rate'):
        rb.run(BAG, rate=-5)
    with pytest.raises(TypeError, match='no_such_option'):
        rb.run(BAG, no_such_option=1)


def test_compare_takes_runs_in_memory_or_folders_and_gives_the_table_and_verdict(tmp_path):
    base = rb.run(BAG, backends=['hsv'], out=tmp_path / 'base')
    cand = rb.run(BAG, backends=['hsv'])
    cmp = rb.compare(base, cand, fail_if=['map50 < -0.02'])
    assert cmp.verdict == 'passed'  # the same detections: the same accuracy
    from replaybench.comparison.output import CSV_COLUMNS

    assert list(cmp.table.columns) == list(CSV_COLUMNS)
    assert list(cmp.table['role']) == ['baseline', 'candidate']
    written = rb.compare(tmp_path / 'base', tmp_path / 'base', out=tmp_path / 'cmp')
    assert written.verdict is None  # no condition, no gate
    csv_rows = pd.read_csv(tmp_path / 'cmp' / 'comparison.csv')
    assert list(csv_rows['role']) == list(written.table['role'])
    assert (tmp_path / 'cmp' / 'comparison.json').is_file()


def test_compare_writes_the_same_markdown_as_the_command_line(tmp_path):
    from replaybench.cli import app

    rb.run(BAG, backends=['hsv'], out=tmp_path / 'base')
    rb.run(BAG, backends=['hsv'], out=tmp_path / 'cand')
    cmp = rb.compare(
        tmp_path / 'base', tmp_path / 'cand', fail_if=['map50 < -0.02'], markdown=tmp_path / 'a.md'
    )
    args = [
        'compare', str(tmp_path / 'base'), str(tmp_path / 'cand'),
        '--fail-if', 'map50 < -0.02', '--markdown', str(tmp_path / 'b.md'),
    ]  # fmt: skip
    assert CliRunner().invoke(app, args).exit_code == 0
    text = (tmp_path / 'a.md').read_text(encoding='utf-8')
    assert text == (tmp_path / 'b.md').read_text(encoding='utf-8')
    assert cmp.verdict == 'passed'
    assert 'passed' in text.lower()
    assert '| hsv' in text or '| `hsv`' in text


def test_peak_in_memory_gives_the_trials_and_the_peak_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    seen: list[Any] = []
    res = rb.peak(
        BAG, backend='null', max_hz=40.0, min_hz=10.0, refine_steps=0, progress=seen.append
    )
    assert list(tmp_path.iterdir()) == []
    assert {'rate_hz', 'ok'} <= set(res.trials.columns)
    assert res.trials['ok'].dtype == bool
    assert len(res.trials) == len(seen) >= 2
    assert res.peak_hz == 40.0  # null keeps up with the highest rate allowed
    assert res.trials['rate_hz'].max() == 40.0


def test_peak_with_a_folder_writes_peak_json_equal_to_the_result(tmp_path):
    res = rb.peak(
        BAG, backend='null', out=tmp_path / 'peak', max_hz=40.0, min_hz=10.0, refine_steps=0
    )
    assert read_peak_result(tmp_path / 'peak') == res
    assert (tmp_path / 'peak' / 'peak.html').is_file()
