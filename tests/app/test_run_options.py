"""One definition of the run options (``replaybench.app.options.RunOptions``): ``run``,
``sweep`` and ``peak`` take them on the command line and in the library, spelled alike, and a
sweep cell's run is the run ``replaybench run`` would make with the same values."""

from __future__ import annotations

import dataclasses
import inspect
from pathlib import Path
from typing import Any

import pytest
import typer

from replaybench.app.options import RunOptions, option_specs, run_options
from replaybench.cli import app
from replaybench.cli._common import cli_name

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'fixtures' / 'bags' / 'jpeg.mcap'

#: a value other than the default for every run option
CHANGED: dict[str, Any] = {
    'rate': '30hz',
    'queue_depth': 2,
    'added_latency_ms': 50.0,
    'warmup': 3,
    'threads': 1,
    'max_frames': 7,
    'start': 0.1,
    'duration': 5.0,
    'topics': ('/camera/image_raw/compressed',),
    'ground_truth': '/gt',
    'config': REPO / 'docs' / 'hsv-default.toml',
    'model': REPO / 'fixtures' / 'model.onnx',
    'model_family': 'yolox',
    'labels': 'coco',
    'conf': 0.4,
    'iou': 0.5,
    'device': 1,
    'engine': 'ort',
    'precision': 'fp16',
    'recorded_topic': '/det',
    'ground_truth_file': REPO / 'gt.json',
    'ground_truth_match': 'seq',
    'ground_truth_image_topic': '/camera/image_raw/compressed',
    'ground_truth_seq_offset': 1,
    'annotations': True,
    'copy_images': True,
    'detections_format': 'rosbag2',
    'report': False,
    'hash_inputs': False,
    'repeat': 3,
    'pipelines': 'per-topic',
    'workers': 'processes',
    'ground_truth_masks': '/labels',
    'ground_truth_disparity': '/gt/disparity',
    'ground_truth_depth': '/gt/depth',
    'depth': True,
    'sync': 'approx:5',
    'stereo': '/cam/left/image_rect,/cam/right/image_rect',
    'tag_family': 'tag25h9',
    'tag_size': 0.16,
    'tag_sizes': '14=0.2,3=0.1',
    'tag_decimation': 1.0,
    'max_tags': 8,
    'tag_refine': 'none',
}


def _flags(command: str) -> set[str]:
    click = typer.main.get_command(app)
    found = click.commands[command]  # type: ignore[attr-defined]
    return {opt for param in found.params for opt in getattr(param, 'opts', [])}


def test_every_run_option_has_a_changed_value_here() -> None:
    assert set(CHANGED) == {f.name for f in dataclasses.fields(RunOptions)}


@pytest.mark.parametrize('command', ['run', 'sweep'])
def test_run_and_sweep_take_every_run_option_spelled_as_run_spells_it(command: str) -> None:
    flags = _flags(command)
    for _name, spec, _default in option_specs():
        assert (spec.cli_flag or spec.flag) in flags, f'{command} lacks {spec.flag}'
        if spec.short:
            assert spec.short in flags


def test_peak_takes_every_run_option_marked_for_peak_and_refuses_the_others() -> None:
    from replaybench.app.peak import peak_config

    flags = _flags('peak')
    for name, spec, _default in option_specs():
        assert ((spec.cli_flag or spec.flag) in flags) == spec.peak, spec.flag
        if spec.peak:
            peak_config(BAG, backend='hsv', **{name: CHANGED[name]})
        else:
            with pytest.raises(TypeError, match=name):
                peak_config(BAG, backend='hsv', **{name: CHANGED[name]})


def test_the_command_parameters_are_the_fields_or_their_negation() -> None:
    from replaybench.cli.run import run

    parameters = inspect.signature(run).parameters
    for name, spec, _default in option_specs():
        assert cli_name(name, spec) in parameters


@pytest.mark.parametrize('left_out', ['stereo', 'topics'])
def test_a_sweep_cell_runs_with_every_option_as_run_config_builds_it(
    tmp_path: Path, left_out: str
) -> None:
    from replaybench.app.run import run_config
    from replaybench.app.sweep import cell_run_config, input_identity, plan_cells, sweep_config

    changed = {k: v for k, v in CHANGED.items() if k != left_out}  # --stereo names the topics
    config = sweep_config([BAG], backends=['hsv'], out=tmp_path / 'sw', **changed)
    assert config.options == run_options(**changed)
    (cell,) = plan_cells([input_identity(BAG, digest=False)], ['hsv'], (), config.options)
    made = cell_run_config(cell, config.options, tmp_path / 'cell', ['replaybench', 'sweep'])
    expected = run_config(
        [BAG], backends=['hsv'], out=tmp_path / 'cell', command=['replaybench', 'sweep'], **changed
    )
    assert made == expected


def test_stereo_names_the_two_topics_and_refuses_topic_beside_it() -> None:
    from replaybench.app.run import run_config
    from replaybench.errors import StereoError, UsageError

    config = run_config([BAG], stereo='/a/left/image_raw, /a/right/image_raw')
    assert config.topics == ['/a/left/image_raw', '/a/right/image_raw']
    with pytest.raises(UsageError, match='without --topic'):
        run_config([BAG], stereo='/l,/r', topics=('/x',))
    with pytest.raises(StereoError, match='two image topics'):
        run_config([BAG], stereo='/only-one')


def test_a_keyword_that_is_no_run_option_is_refused_by_run_and_sweep(tmp_path: Path) -> None:
    from replaybench.app.run import run_config
    from replaybench.app.sweep import sweep_config

    with pytest.raises(TypeError, match='max_frame'):
        run_config([BAG], max_frame=3)
    with pytest.raises(TypeError, match='max_frame'):
        sweep_config([BAG], backends=['hsv'], out=tmp_path, max_frame=3)
