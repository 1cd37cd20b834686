"""``replaybench.app.compare``: the command line and the API parse into one ``CompareConfig``
and compare through ``run_compare``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

import replaybench as rb
from replaybench.app.compare import CompareConfig, compare_config, compare_lines, run_compare
from replaybench.errors import UsageError

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


@pytest.fixture(scope='module')
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp('runs')
    for name in ('a', 'b'):
        rb.run(BAG, backends=['hsv', 'null'], out=base / name, report=False)
    return base / 'a', base / 'b'


def test_compare_config_holds_paths_and_a_single_condition_as_a_tuple(tmp_path: Path) -> None:
    config = compare_config(['runs/a', tmp_path], fail_if='p99_ms > +10%', out='cmp')
    assert config == CompareConfig(
        runs=(Path('runs/a'), tmp_path), fail_if=('p99_ms > +10%',), out=Path('cmp')
    )
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.strict = True  # type: ignore[misc]


def test_a_bad_condition_is_refused_before_any_run_is_read(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match='p99_ms >> 3'):
        compare_config([tmp_path / 'missing', tmp_path / 'gone'], fail_if=['p99_ms >> 3'])


def test_run_compare_writes_the_three_files_only_when_asked(
    two_runs: tuple[Path, Path], tmp_path: Path
) -> None:
    quiet = run_compare(compare_config(two_runs))
    assert quiet.written == ()
    assert quiet.verdict is None
    assert quiet.exit_code == 0
    out = tmp_path / 'cmp'
    loud = run_compare(compare_config(two_runs, fail_if=['map50 < -0.5'], out=out))
    assert [p.name for p in loud.written] == [
        'comparison.csv',
        'comparison.html',
        'comparison.json',
    ]
    assert all(p.is_file() for p in loud.written)
    assert loud.verdict == 'passed'
    document = json.loads((out / 'comparison.json').read_text(encoding='utf-8'))
    assert document['gate']['verdict'] == 'passed'
    lines = compare_lines(loud)
    assert (False, f'JSON: {out / "comparison.json"}') in lines
    assert lines[-3:] == [
        (False, f'Comparison: {out / "comparison.html"}'),
        (False, f'CSV: {out / "comparison.csv"}'),
        (False, f'JSON: {out / "comparison.json"}'),
    ]


def test_the_api_and_the_command_line_compare_alike(two_runs: tuple[Path, Path]) -> None:
    outcome = run_compare(compare_config(two_runs, fail_if=['map50 < -0.5']))
    result = rb.compare(*two_runs, fail_if='map50 < -0.5')
    assert result.verdict == outcome.verdict == 'passed'
    assert [(r.run_index, r.backend, r.topic, r.role) for r in result.rows] == [
        (r.run, r.backend, r.topic, r.role) for r in outcome.comparison.rows
    ]


def test_an_unwritable_out_is_bad_input(two_runs: tuple[Path, Path], tmp_path: Path) -> None:
    blocker = tmp_path / 'file'
    blocker.write_text('x', encoding='utf-8')
    with pytest.raises(UsageError, match='cannot write into') as caught:
        run_compare(compare_config(two_runs, out=blocker / 'cmp'))
    assert caught.value.exit_code == 2


def test_the_command_line_chooses_the_baseline_run_and_backend(
    two_runs: tuple[Path, Path],
) -> None:
    from typer.testing import CliRunner

    from replaybench.cli import app

    a, b = two_runs
    runner = CliRunner()
    result = runner.invoke(app, ['compare', str(a), str(b), '--baseline', '1'])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[0].startswith(f'baseline: {b.name} ')
    result = runner.invoke(app, ['compare', str(a), '--baseline-backend', 'null'])
    assert result.exit_code == 0, result.output
    assert '(backend null)' in result.stdout.splitlines()[0]
    assert any('· hsv · ' in line and 'vs null' in line for line in result.stdout.splitlines())
    result = runner.invoke(app, ['compare', str(a), str(b), '--baseline', '2'])
    assert result.exit_code == 2
    assert result.stderr.strip() == (
        'replaybench: error: baseline index 2 out of range: 2 run folder(s) given'
    )
    result = runner.invoke(app, ['compare', str(a), str(b), '--baseline-backend', 'cuda'])
    assert result.exit_code == 2
    assert "baseline backend 'cuda' is not in" in result.stderr
