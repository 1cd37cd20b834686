"""The command line on a machine without a usable GPU: exit 2 with the reason, nothing written."""

from __future__ import annotations

import pytest
from backends.gpu.gpuhelpers import FIXTURE_BAGS
from typer.testing import CliRunner

from replaybench.backends import get_backend
from replaybench.cli import app

RAW = FIXTURE_BAGS / 'rgb8_raw.mcap'
runner = CliRunner()


@pytest.mark.parametrize('name', ['cuda', 'tensorrt', 'hsv-cuda'])
def test_running_an_unavailable_gpu_backend_exits_2_with_the_reason(tmp_path, name):
    status = get_backend(name).available()
    if status.ok:
        pytest.skip(f'{name} is available on this machine')
    out = tmp_path / 'run'
    result = runner.invoke(app, ['run', str(RAW), '--backend', name, '--out', str(out)])
    assert result.exit_code == 2, result.output
    assert f"backend '{name}' is not available here: {status.reason}" in result.output
    assert not out.exists()


def test_backends_lists_each_gpu_backend_with_its_state():
    result = runner.invoke(app, ['backends'])
    assert result.exit_code == 0, result.output
    lines = {line.split()[0]: line for line in result.output.splitlines() if line.strip()}
    for name in ('cuda', 'tensorrt', 'hsv-cuda'):
        status = get_backend(name).available()
        expected = 'available' if status.ok else f'unavailable: {status.reason}'
        assert expected in lines[name]
