"""compare and its gate on tag accuracy: two runs of the apriltag backend over the same tag bag,
one told the right tag sizes and one 0.22 m for every tag, given explicitly over the sizes the
bag records (a wrong scale: the translations grow, the rotations and the recall stay)."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import pytest

import replaybench as rb
from replaybench.fixtures.tags import write_tag_mcap

if TYPE_CHECKING:
    from pathlib import Path


@pytest.fixture(scope='module')
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp('tagcmp')
    bag = write_tag_mcap(base / 'tags.mcap', 6)
    sized = base / 'sized'
    unsized = base / 'unsized'
    rb.run(bag, backends='apriltag', out=sized, tag_sizes='0=0.16,3=0.1,14=0.2')
    rb.run(bag, backends='apriltag', out=unsized, tag_size=0.22)
    return sized, unsized


def test_a_wrong_tag_size_fails_a_translation_gate_and_passes_recall_and_rotation(
    two_runs: tuple[Path, Path], tmp_path: Path
) -> None:
    sized, unsized = two_runs
    comparison = rb.compare(
        sized,
        unsized,
        fail_if=['tag_trans_err_m > +0.05', 'tag_recall < -0.02', 'tag_rot_err_deg > +0.5'],
        out=tmp_path / 'cmp',
    )
    assert comparison.gate is not None
    verdicts = {g.condition: g.verdict for g in comparison.gate.results}
    assert verdicts == {
        'tag_trans_err_m > +0.05': 'failed',
        'tag_recall < -0.02': 'passed',
        'tag_rot_err_deg > +0.5': 'passed',
    }
    assert comparison.verdict == 'failed'
    document = json.loads((tmp_path / 'cmp' / 'comparison.json').read_text())
    row = next(r for r in document['rows'] if r['role'] == 'candidate')
    assert row['metrics']['tag_recall']['value'] == pytest.approx(17 / 18)
    header = (tmp_path / 'cmp' / 'comparison.csv').read_text().splitlines()[0].split(',')
    at = header.index('tag_rot_err_deg')
    assert header[at : at + 3] == [
        'tag_rot_err_deg',
        'tag_rot_err_deg_baseline',
        'tag_rot_err_deg_delta',
    ]
    assert header.index('flags') < at < header.index('recorded_pipeline_ms')


def test_the_command_line_gate_exits_1_on_a_failed_tag_condition(
    two_runs: tuple[Path, Path],
) -> None:
    import subprocess
    import sys

    sized, unsized = two_runs
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'compare', str(sized), str(unsized),
         '--fail-if', 'tag_trans_err_pct > +5'],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 1, done.stderr
    assert 'tag_trans_err_pct' in done.stdout + done.stderr
