"""The busy backend: a known cost per frame, set by options or a TOML file."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from replaybench.backends import BackendOptions, get_backend
from replaybench.backends.busywait import DEFAULT_MS, BusyBackend, spin_options
from replaybench.cli import app
from replaybench.errors import BackendError
from replaybench.types import Frame

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


def _frame() -> Frame:
    return Frame('/cam', 0, 0, 0, 'cam', np.zeros((4, 4, 3), dtype=np.uint8), 'bgr8', 'bgr8')


def test_the_busy_backend_is_registered_and_spins_10_ms_by_default() -> None:
    assert get_backend('busy') is BusyBackend
    backend = BusyBackend()
    assert (backend.ms, backend.clock_name) == (DEFAULT_MS, 'wall')
    assert backend.info() == {'busy_ms': 10.0, 'busy_clock': 'wall', 'detections': 'none'}


@pytest.mark.parametrize('clock', ['wall', 'cpu'])
def test_a_frame_costs_at_least_the_time_asked_for_on_its_clock(clock: str) -> None:
    backend = BusyBackend(BackendOptions(extra=spin_options(3.0, clock)))
    read = time.perf_counter if clock == 'wall' else time.thread_time
    backend.open()
    start = read()
    result = backend.detect(_frame())
    spent = read() - start
    backend.close()
    assert result.detections == ()
    assert result.stages.infer_ns is not None
    assert result.stages.infer_ns >= 3_000_000
    assert spent >= 0.003  # spinning ends only once its clock has moved 3 ms


def test_the_cost_can_come_from_a_toml_file_and_options_win_over_it(tmp_path: Path) -> None:
    config = tmp_path / 'busy.toml'
    config.write_text('ms = 2.5\nclock = "cpu"\n', encoding='utf-8')
    from_file = BusyBackend(BackendOptions(config=config))
    assert (from_file.ms, from_file.clock_name) == (2.5, 'cpu')
    both = BusyBackend(BackendOptions(config=config, extra={'busy_ms': '7'}))
    assert (both.ms, both.clock_name) == (7.0, 'cpu')


@pytest.mark.parametrize(
    ('extra', 'toml', 'message'),
    [
        ({'busy_ms': 'fast'}, None, "busy_ms must be a number of milliseconds, not 'fast'"),
        ({'busy_ms': '-1'}, None, 'busy_ms must be between 0 and 60000, not -1'),
        ({'busy_ms': 'nan'}, None, 'busy_ms must be a number'),
        ({'busy_clock': 'gpu'}, None, "busy_clock must be wall or cpu, not 'gpu'"),
        ({}, 'ms = 1\nspeed = 2\n', "unknown key 'speed' (known: clock, ms)"),
        ({}, 'ms = [1]\n', 'busy_ms must be a number of milliseconds'),
        ({}, 'ms = \n', 'is not valid TOML'),
    ],
)
def test_bad_settings_are_one_line_backend_errors(
    tmp_path: Path, extra: dict[str, str], toml: str | None, message: str
) -> None:
    config = None
    if toml is not None:
        config = tmp_path / 'busy.toml'
        config.write_text(toml, encoding='utf-8')
    with pytest.raises(BackendError) as info:
        BusyBackend(BackendOptions(config=config, extra=extra))
    assert message in str(info.value)
    assert '\n' not in str(info.value)


def test_a_bad_cost_on_the_command_line_exits_2_with_one_line(tmp_path: Path) -> None:
    if not RAW.is_file():
        pytest.skip(f'{RAW} missing')
    config = tmp_path / 'busy.toml'
    config.write_text('ms = -3\n', encoding='utf-8')
    result = CliRunner().invoke(
        app,
        ['run', str(RAW), '--backend', 'busy', '--config', str(config), '--out',
         str(tmp_path / 'run'), '--no-report'],
    )  # fmt: skip
    assert result.exit_code == 2
    assert 'busy_ms must be between 0 and 60000, not -3' in result.output
    assert 'Traceback' not in result.output
