"""Tag sizes from the bag's own ``replaybench.tags`` metadata, a wrong size named per tag id, and
the corner refinement as a run option (docs/fiducials.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from replaybench.backends.aruco import ArucoBackend
from replaybench.backends.base import BackendOptions
from replaybench.cli import app
from replaybench.errors import BackendError
from replaybench.fiducials.bagsizes import METADATA_NAME, bag_size_keys, read_mcap_metadata
from replaybench.fixtures.tags import TAG_SIZES, write_tag_mcap
from replaybench.fixtures.writer import write_rosbag1

#: the committed tag bag (10 frames, 640x480), as README's example runs it
COMMITTED = Path(__file__).resolve().parents[2] / 'fixtures' / 'tags' / 'tags.mcap'


@pytest.fixture(scope='module')
def tag_bag() -> Path:
    return COMMITTED


def test_the_tag_writer_records_the_sizes_in_every_bag_it_writes(tmp_path: Path) -> None:
    bag = write_tag_mcap(tmp_path / 'small.mcap', 1, (160, 120), distortion='equidistant')
    assert read_mcap_metadata(bag, METADATA_NAME) == read_mcap_metadata(COMMITTED, METADATA_NAME)


def _run(bag: Path, out: Path, *args: str) -> tuple[int, str, dict[str, Any]]:
    result = CliRunner().invoke(
        app,
        ['run', str(bag), '--backend', 'aruco', '--out', str(out), '--no-report', *args],
    )
    document = json.loads((out / 'run.json').read_text()) if result.exit_code == 0 else {}
    return result.exit_code, result.output, document


def test_a_tag_fixture_bag_records_its_tag_sizes_in_mcap_metadata(tag_bag: Path) -> None:
    record = read_mcap_metadata(tag_bag, METADATA_NAME)
    assert record == {'tag_size': '0.16', 'tag_sizes': '0=0.16,3=0.1,14=0.2'}
    assert TAG_SIZES == {0: 0.16, 3: 0.1, 14: 0.2}


def test_a_run_without_tag_sizes_uses_the_bags_and_says_so(tag_bag: Path, tmp_path: Path) -> None:
    code, output, document = _run(tag_bag, tmp_path / 'run')
    assert code == 0, output
    info = document['backends'][0]['info']
    assert info['tag_sizes_m'] == {'0': 0.16, '3': 0.1, '14': 0.2}
    assert info['tag_sizes_from'] == "the bag (tags.mcap's replaybench.tags metadata)"
    assert (
        "tags: aruco: tag sizes 0.16 m (0=0.16, 3=0.1, 14=0.2) from the bag (tags.mcap's "
        'replaybench.tags metadata)' in output
    )
    accuracy = document['summary'][0]['tag_accuracy']
    assert accuracy['trans_err_pct'] < 2.0
    assert accuracy['size_hints'] == []


def test_explicit_tag_sizes_win_over_the_bags(tag_bag: Path, tmp_path: Path) -> None:
    code, output, document = _run(tag_bag, tmp_path / 'run', '--tag-size', '0.3')
    assert code == 0, output
    info = document['backends'][0]['info']
    assert (info['tag_size_m'], info['tag_sizes_m']) == (0.3, {})
    assert info['tag_sizes_from'] == 'the options (--tag-size / --tag-sizes)'


def test_a_wrong_tag_size_is_named_with_the_size_its_distances_imply(
    tag_bag: Path, tmp_path: Path
) -> None:
    code, output, document = _run(tag_bag, tmp_path / 'run', '--tag-size', '0.22')
    assert code == 0, output
    hints = document['summary'][0]['tag_accuracy']['size_hints']
    assert [h['tag_id'] for h in hints] == [0, 3, 14]
    by_id = {h['tag_id']: h for h in hints}
    # the distance scales as the size: 0.22 / 0.16, 0.22 / 0.1, 0.22 / 0.2
    for tag_id, true_size in TAG_SIZES.items():
        assert by_id[tag_id]['scale'] == pytest.approx(0.22 / true_size, rel=0.02)
        assert by_id[tag_id]['suggested_size_m'] == pytest.approx(true_size, rel=0.02)
        assert by_id[tag_id]['spread_pct'] < 3.0
    line = 'tag 0: distances are 1.38x the truth: is its size 0.16 m rather than 0.22 m?'
    assert by_id[0]['line'] == line
    assert f'tags: aruco /camera/image_raw: {line}' in output
    assert 'tag 3: distances are 2.2' in output
    assert 'is its size 0.1 m rather than 0.22 m?' in output


def test_the_readme_sizes_give_no_size_hint(tag_bag: Path, tmp_path: Path) -> None:
    code, output, document = _run(
        tag_bag, tmp_path / 'run', '--tag-size', '0.16', '--tag-sizes', '14=0.2,3=0.1'
    )
    assert code == 0, output
    assert document['summary'][0]['tag_accuracy']['size_hints'] == []
    assert 'distances are' not in output


def test_a_ros1_bag_has_no_recorded_sizes_and_the_default_says_why(tmp_path: Path) -> None:
    bag = write_rosbag1(tmp_path / 'scene.bag', 1, (64, 48))
    keys = bag_size_keys([bag])
    assert keys == {'bag_sizes_from': 'scene.bag is no MCAP file and so records no tag sizes'}
    backend = ArucoBackend(BackendOptions(tag_options=keys))
    assert backend.tags.sizes.default == 0.22
    assert backend.tags.describe()['tag_sizes_from'] == (
        'the default (0.22 m): scene.bag is no MCAP file and so records no tag sizes'
    )


def test_inputs_recording_different_sizes_are_refused_unless_sizes_are_given(
    tag_bag: Path, tmp_path: Path
) -> None:
    other = write_rosbag1(tmp_path / 'scene.bag', 1, (64, 48))
    keys = bag_size_keys([tag_bag, other])
    with pytest.raises(BackendError, match='the inputs record different tag sizes'):
        ArucoBackend(BackendOptions(tag_options=keys))
    given = ArucoBackend(BackendOptions(tag_options={**keys, 'tag_size': '0.1'}))
    assert given.tags.sizes.default == 0.1


def test_tag_refine_reaches_the_backend_and_bad_values_exit_2_in_one_line(
    tag_bag: Path, tmp_path: Path
) -> None:
    code, output, document = _run(tag_bag, tmp_path / 'a', '--tag-refine', 'apriltag')
    assert code == 0, output
    assert document['backends'][0]['info']['refine'] == 'apriltag'
    code, output, document = _run(tag_bag, tmp_path / 'b')
    assert document['backends'][0]['info']['refine'] == 'subpix'
    code, output, _ = _run(tag_bag, tmp_path / 'c', '--tag-refine', 'sharp')
    assert code == 2
    assert output.strip().splitlines() == [
        (
            "replaybench: error: unknown --tag-refine 'sharp': use none or subpix or contour or "
            'apriltag or edges'
        )
    ]
    code, output, _ = _run(tag_bag, tmp_path / 'd', '--tag-refine', 'edges')
    assert code == 2
    assert output.strip().splitlines() == [
        (
            'replaybench: error: aruco: refine (--tag-refine) must be one of subpix, apriltag, '
            "contour, none, got 'edges'"
        )
    ]


def test_refine_is_a_sweep_parameter_checked_before_any_cell_runs(tag_bag: Path) -> None:
    from replaybench.app.options import RunOptions
    from replaybench.app.sweep.plan import (
        check_backend_options,
        input_identity,
        parse_params,
        plan_cells,
    )
    from replaybench.errors import UsageError

    axes = parse_params(['aruco.refine=none,subpix,contour,apriltag'], ['aruco'])
    inp = input_identity(tag_bag, digest=False)
    cells = plan_cells([inp], ['aruco'], axes, RunOptions())
    assert [c.params for c in cells] == [
        (('refine', r),) for r in ('none', 'subpix', 'contour', 'apriltag')
    ]
    check_backend_options(cells, RunOptions())
    bad = plan_cells(
        [inp], ['aruco'], parse_params(['aruco.refine=edges'], ['aruco']), RunOptions()
    )
    with pytest.raises(UsageError, match=r'aruco \(refine=edges\): aruco: refine'):
        check_backend_options(bad, RunOptions())
