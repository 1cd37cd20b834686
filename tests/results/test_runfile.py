"""run.json / summary.csv writing, the environment record, and reading a run folder back."""

from __future__ import annotations

import csv
import json
import math
import platform
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

from replaybench.errors import SourceError
from replaybench.results.atomic import write_json_atomic
from replaybench.results.folder import load_run
from replaybench.results.machine import environment
from replaybench.results.model import RUN_SCHEMA_VERSION as SCHEMA_VERSION
from replaybench.results.records import FrameRecord, FramesCsvWriter
from replaybench.results.stats import SUMMARY_CSV_COLUMNS, summarize
from replaybench.results.summarycsv import write_summary_csv

if TYPE_CHECKING:
    from pathlib import Path


def _strict_loads(text: str) -> Any:
    def refuse(name: str) -> None:
        msg = f'non-standard JSON constant {name}'
        raise AssertionError(msg)

    return json.loads(text, parse_constant=refuse)


def _records() -> list[FrameRecord]:
    return [
        FrameRecord(0, 'hsv', '/cam', i, i, i, 'ok', '', i == 0, False, i * 0.1, i * 0.1,
                    i * 0.1 + 0.01, 0.0, 1.0, None, 8.0, None, None, None, 10.0 + i, i)
        for i in range(5)
    ]  # fmt: skip


def write_run_json(path: Path, run: dict[str, Any]) -> None:
    """A hand-made run.json: ``run`` with ``schema_version`` first when it is missing."""
    if 'schema_version' not in run:
        run = {'schema_version': SCHEMA_VERSION, **run}
    write_json_atomic(path, run)


def _run_folder(tmp_path: Path, **run: Any) -> Path:
    with FramesCsvWriter(tmp_path / 'frames.csv') as writer:
        writer.write_many(_records())
    write_run_json(tmp_path / 'run.json', {'status': 'complete', **run})
    return tmp_path


def test_json_has_no_nan_or_infinity(tmp_path: Path) -> None:
    path = tmp_path / 'out.json'
    write_json_atomic(
        path,
        {
            'nan': math.nan,
            'inf': [math.inf, -math.inf, 1.5],
            'np': {'f': np.float32(2.5), 'i': np.int64(7), 'bad': np.float64('nan')},
            'tuple': (1, 2),
            'path': tmp_path,
        },
    )
    data = _strict_loads(path.read_text())
    assert data == {
        'nan': None,
        'inf': [None, None, 1.5],
        'np': {'f': 2.5, 'i': 7, 'bad': None},
        'tuple': [1, 2],
        'path': str(tmp_path),
    }
    assert list(tmp_path.iterdir()) == [path]


def test_json_keeps_key_order_and_is_indented(tmp_path: Path) -> None:
    path = tmp_path / 'out.json'
    write_json_atomic(path, {'z': 1, 'a': {'y': 2, 'b': 3}})
    text = path.read_text()
    assert text.index('"z"') < text.index('"a"') < text.index('"y"') < text.index('"b"')
    assert '\n  "a": {\n    "y": 2' in text


def test_unserialisable_values_fail_without_touching_the_file(tmp_path: Path) -> None:
    path = tmp_path / 'out.json'
    write_json_atomic(path, {'ok': 1})
    with pytest.raises(TypeError, match='object'):
        write_json_atomic(path, {'bad': object()})
    assert _strict_loads(path.read_text()) == {'ok': 1}
    assert list(tmp_path.iterdir()) == [path]


def test_run_json_gets_the_schema_version_first(tmp_path: Path) -> None:
    write_run_json(tmp_path / 'run.json', {'status': 'complete'})
    text = (tmp_path / 'run.json').read_text()
    assert next(iter(json.loads(text))) == 'schema_version'
    assert json.loads(text)['schema_version'] == SCHEMA_VERSION


def test_environment_describes_this_machine_as_plain_json(tmp_path: Path) -> None:
    env = environment()
    write_json_atomic(tmp_path / 'env.json', env)
    assert _strict_loads((tmp_path / 'env.json').read_text()) == env
    assert env['python']['version'] == platform.python_version()
    assert env['cpu']['logical_cores'] >= 1
    assert env['cpu']['model']
    assert env['packages']['numpy'] == np.__version__
    assert isinstance(env['packages']['opencv']['version'], str)
    assert isinstance(env['packages']['opencv']['threads'], int)
    assert isinstance(env['gpus'], list)
    assert env['os']['system'] == platform.system()


def test_summary_csv_has_one_row_per_group(tmp_path: Path) -> None:
    path = tmp_path / 'summary.csv'
    summaries = summarize(_records())
    write_summary_csv(path, summaries)
    with path.open(newline='') as file:
        rows = list(csv.DictReader(file))
    assert tuple(rows[0]) == SUMMARY_CSV_COLUMNS
    [row] = rows
    assert row['backend'] == 'hsv'
    assert row['measured'] == '4'
    assert row['latency_ms_p50'] == '12.5000'
    assert row['map50'] == ''
    assert row['h2d_ms_mean'] == ''
    assert sorted(p.name for p in tmp_path.iterdir()) == ['summary.csv']


def test_load_run_reads_run_json_and_frames(tmp_path: Path) -> None:
    run_dir = _run_folder(tmp_path, outputs={'frames_csv': 'frames.csv'})
    data = load_run(run_dir)
    assert data.run.status == 'complete'
    assert [r.latency_ms for r in data.frames] == [10.0, 11.0, 12.0, 13.0, 14.0]
    assert [r.warmup for r in data.frames] == [True, False, False, False, False]
    assert data.dir == run_dir


def test_load_run_without_run_json_says_so(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r'no run\.json'):
        load_run(tmp_path)


def test_load_run_on_a_missing_folder_says_so(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match='not a directory'):
        load_run(tmp_path / 'missing')


def test_load_run_reports_where_json_is_broken(tmp_path: Path) -> None:
    (tmp_path / 'run.json').write_text('{"schema_version": 1,\n "status": }')
    with pytest.raises(SourceError, match='invalid JSON at line 2') as caught:
        load_run(tmp_path)
    assert isinstance(caught.value.__cause__, json.JSONDecodeError)  # the parser's, for --debug


@pytest.mark.parametrize('content', ['[1, 2]', '{"status": "complete"}', '{"schema_version": "1"}'])
def test_load_run_refuses_a_run_json_without_a_valid_schema(tmp_path: Path, content: str) -> None:
    (tmp_path / 'run.json').write_text(content)
    with pytest.raises(SourceError, match=r'schema_version|JSON object'):
        load_run(tmp_path)


def test_load_run_refuses_a_newer_schema(tmp_path: Path) -> None:
    _run_folder(tmp_path)
    write_json_atomic(tmp_path / 'run.json', {'schema_version': SCHEMA_VERSION + 1})
    with pytest.raises(SourceError, match='newer than this replaybench supports'):
        load_run(tmp_path)


def test_load_run_needs_frames_csv(tmp_path: Path) -> None:
    write_run_json(tmp_path / 'run.json', {'status': 'complete'})
    with pytest.raises(SourceError, match=r'frames\.csv is missing'):
        load_run(tmp_path)


def test_load_run_does_not_follow_frames_csv_outside_the_folder(tmp_path: Path) -> None:
    run_dir = tmp_path / 'run'
    run_dir.mkdir()
    _run_folder(tmp_path)
    write_run_json(run_dir / 'run.json', {'outputs': {'frames_csv': '../frames.csv'}})
    with pytest.raises(SourceError, match='outside the run folder'):
        load_run(run_dir)


def test_environment_lists_the_gpus_nvidia_smi_reports(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    tool = tmp_path / 'nvidia-smi'
    tool.write_text(
        '#!/bin/sh\n'
        'echo "NVIDIA H100 80GB HBM3, 550.54.15, 81559 MiB"\n'
        'echo "NVIDIA L4, 550.54.15, 23034 MiB"\n'
    )
    tool.chmod(0o755)
    monkeypatch.setenv('PATH', f'{tmp_path}:/usr/bin:/bin')
    assert environment()['gpus'] == [
        {
            'name': 'NVIDIA H100 80GB HBM3',
            'driver_version': '550.54.15',
            'memory_total': '81559 MiB',
        },
        {'name': 'NVIDIA L4', 'driver_version': '550.54.15', 'memory_total': '23034 MiB'},
    ]


def test_a_failing_nvidia_smi_means_no_gpus(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    tool = tmp_path / 'nvidia-smi'
    tool.write_text('#!/bin/sh\necho "NVIDIA-SMI has failed" >&2\nexit 9\n')
    tool.chmod(0o755)
    monkeypatch.setenv('PATH', f'{tmp_path}:/usr/bin:/bin')
    assert environment()['gpus'] == []
