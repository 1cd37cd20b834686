"""``replaybench.app.sweep``: the command line and the API parse into one ``SweepConfig``,
and each cell runs with the ``RunConfig`` that ``replaybench run`` would build."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from replaybench.app.options import RunOptions
from replaybench.app.run import run_config
from replaybench.app.sweep import (
    SweepConfig,
    cell_run_config,
    input_identity,
    plan_cells,
    sweep_config,
)
from replaybench.errors import UsageError
from replaybench.replay.instances import instance_options

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


def test_sweep_config_parses_the_params_and_keeps_the_shared_run_options(tmp_path: Path) -> None:
    config = sweep_config(
        [BAG],
        backends=['hsv', 'null'],
        out=tmp_path / 'sweep',
        params=['hsv.min_area=50,100'],
        max_frames=5,
        threads=1,
        command=['replaybench', 'sweep'],
    )
    assert isinstance(config, SweepConfig)
    assert config.inputs == (BAG,)
    assert config.backends == ('hsv', 'null')
    assert [tuple(a) for a in config.axes] == [('hsv', 'min_area', ('50', '100'))]
    assert config.options == RunOptions(max_frames=5, threads=1)
    assert config.command == ('replaybench', 'sweep')
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.pack = True  # type: ignore[misc]


@pytest.mark.parametrize(
    ('options', 'named'),
    [
        ({'backends': []}, 'no backend given'),
        ({'backends': ['hsv', 'hsv']}, 'each --backend may be given once'),
        ({'max_retries': -1}, '--max-retries'),
        ({'engine': 'warp'}, 'warp'),
        ({'rate': 'fast'}, 'fast'),
        ({'params': ['nope.x=1']}, 'nope'),
    ],
)
def test_sweep_config_refuses_bad_options_before_reading_anything(
    options: dict[str, object], named: str, tmp_path: Path
) -> None:
    given: dict[str, object] = {'backends': ['hsv'], 'out': tmp_path / 'sweep', **options}
    with pytest.raises(UsageError) as caught:
        sweep_config([tmp_path / 'not-there.mcap'], **given)  # type: ignore[arg-type]
    assert named in str(caught.value)
    assert not (tmp_path / 'sweep').exists()


def test_a_cell_runs_with_the_run_commands_config_and_its_param_values(tmp_path: Path) -> None:
    config = sweep_config(
        [BAG],
        backends=['hsv'],
        out=tmp_path / 'sweep',
        params=['hsv.min_area=77'],
        rate='30hz',
        max_frames=5,
        topics=['/camera/image_raw'],
        threads=1,
    )
    (cell,) = plan_cells([input_identity(BAG)], ['hsv'], config.axes, config.options)
    made = cell_run_config(cell, config.options, tmp_path / 'cell', ['replaybench', 'sweep'])
    # the cell is `replaybench run BAG --backend hsv --param hsv.min_area=77` with the options
    expected = run_config(
        [BAG],
        backends=['hsv'],
        params=['hsv.min_area=77'],
        out=tmp_path / 'cell',
        rate='30hz',
        max_frames=5,
        topics=['/camera/image_raw'],
        threads=1,
        command=['replaybench', 'sweep'],
    )
    assert dataclasses.replace(made, input_sha256=None) == expected
    assert made.options.threads == 1
    assert made.instance('hsv').params == (('min_area', '77'),)
    assert instance_options(made.options, made.instance('hsv')).extra == {'min_area': '77'}
    # the driver's digest goes with the cell: the run on the node does not hash the input
    assert made.input_sha256 == (cell.input.sha256,)
    assert made.hash_inputs is True
