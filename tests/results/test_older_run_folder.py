"""Run folders written before run.json's schema_version 2 hold their MCAP as detections.mcap,
named by ``outputs.detections_mcap``: ``load_run``, ``report`` and ``compare`` read them beside
folders that hold outputs.mcap (docs/outputs.md)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

import replaybench as rb
from replaybench.cli import app
from replaybench.results.io import read_run_result

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
runner = CliRunner()


def _as_older(run_dir: Path) -> None:
    """``run_dir`` as a replaybench of run.json schema_version 1 wrote it: detections.mcap, and
    run.json's ``outputs`` naming it under ``detections_mcap`` (the key's place kept)."""
    (run_dir / 'outputs.mcap').rename(run_dir / 'detections.mcap')
    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    document['schema_version'] = 1
    document['outputs'] = {
        ('detections_mcap' if k == 'outputs_mcap' else k): v for k, v in document['outputs'].items()
    }
    document['outputs']['detections_mcap'] = 'detections.mcap'
    (run_dir / 'run.json').write_text(json.dumps(document, indent=2), encoding='utf-8')


@pytest.fixture(scope='module')
def folders(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """(a run folder of schema_version 1, the same run as written now)."""
    base = tmp_path_factory.mktemp('older')
    new = base / 'new'
    rb.run(str(RAW), backends=['hsv', 'null'], max_frames=25, out=new)
    older = base / 'older'
    shutil.copytree(new, older)
    _as_older(older)
    return older, new


def test_the_run_writes_outputs_mcap_and_run_json_names_it(folders: tuple[Path, Path]) -> None:
    _, new = folders
    document = json.loads((new / 'run.json').read_text(encoding='utf-8'))
    assert document['schema_version'] == 2
    assert next(iter(document['outputs'])) == 'outputs_mcap'
    assert document['outputs']['outputs_mcap'] == 'outputs.mcap'
    assert 'detections_mcap' not in document['outputs']
    assert (new / 'outputs.mcap').is_file()
    assert not (new / 'detections.mcap').exists()


def test_load_run_of_an_older_folder_names_its_detections_mcap(
    folders: tuple[Path, Path],
) -> None:
    older, new = folders
    old_run, new_run = rb.load_run(older), rb.load_run(new)
    assert old_run.schema_version == 1
    assert old_run.outputs is not None
    assert new_run.outputs is not None
    assert old_run.outputs.outputs_mcap == 'detections.mcap'
    assert old_run.outputs.detections_mcap == 'detections.mcap'  # the older name, kept
    assert new_run.outputs.outputs_mcap == 'outputs.mcap'
    assert (older / old_run.outputs.outputs_mcap).read_bytes() == (
        new / new_run.outputs.outputs_mcap
    ).read_bytes()
    assert old_run.summary_rows == new_run.summary_rows
    assert old_run.frame_records == new_run.frame_records
    assert read_run_result(older).outputs == old_run.outputs


def test_report_renders_an_older_folder_again(folders: tuple[Path, Path]) -> None:
    older, _ = folders
    (older / 'report.html').unlink()
    result = runner.invoke(app, ['report', str(older)])
    assert result.exit_code == 0, result.output
    page = (older / 'report.html').read_text(encoding='utf-8')
    assert 'hsv' in page
    assert 'null' in page


def test_compare_reads_an_older_folder_beside_a_newer_one(
    folders: tuple[Path, Path], tmp_path: Path
) -> None:
    older, new = folders
    out = tmp_path / 'cmp'
    result = runner.invoke(
        app, ['compare', str(older), str(new), '--out', str(out), '--fail-if', 'p99_ms > +1000%']
    )
    assert result.exit_code == 0, result.output
    comparison = json.loads((out / 'comparison.json').read_text(encoding='utf-8'))
    assert len(comparison['runs']) == 2
