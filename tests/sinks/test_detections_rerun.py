"""Reruns of one bag write the same outputs.mcap, byte for byte (the CLI, real bags)."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner

from replaybench._version import __version__
from replaybench.cli import app

BAGS = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags'


def _detections(bag: Path, out: Path) -> bytes:
    result = CliRunner().invoke(
        app,
        [
            'run',
            str(bag),
            '--backend',
            'hsv',
            '--backend',
            'null',
            '--annotations',
            '--copy-images',
            '--no-report',
            '--out',
            str(out),
        ],
    )
    assert result.exit_code == 0, result.output
    return (out / 'outputs.mcap').read_bytes()


@pytest.mark.parametrize('bag', ['rgb8.bag', 'bgr8_rosbag2', 'jpeg.mcap'])
def test_two_runs_of_the_same_bag_write_byte_identical_outputs_mcap(
    tmp_path: Path, bag: str
) -> None:
    first = _detections(BAGS / bag, tmp_path / 'a')
    second = _detections(BAGS / bag, tmp_path / 'b')
    assert first == second
    with (tmp_path / 'a' / 'outputs.mcap').open('rb') as stream:
        reader = make_reader(stream)
        header = reader.get_header()
        summary = reader.get_summary()
    # the header names replaybench, not the writing library's own (version-dependent) string
    assert (header.profile, header.library) == ('ros2', f'replaybench {__version__}')
    assert summary is not None
    assert summary.statistics is not None
    assert summary.statistics.message_count > 0
    assert {c.compression for c in summary.chunk_indexes} == {'zstd'}
