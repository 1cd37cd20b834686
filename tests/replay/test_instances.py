"""The engine's side of instances (``replaybench.replay.instances``): a ``RunConfig`` built
without the command line is checked as ``--backend`` is, and an instance's options are the
run's with its own parameters on top."""

from __future__ import annotations

from pathlib import Path

import pytest

from replaybench.backends.base import BackendOptions
from replaybench.errors import UsageError
from replaybench.replay.config import RunConfig
from replaybench.replay.instances import (
    BackendInstance,
    instance_options,
    parse_instances,
    with_params,
)
from replaybench.replay.runner import run_benchmark

RAW = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


@pytest.mark.parametrize(
    ('backends', 'instances', 'said'),
    [
        (['hsv', 'hsv'], {}, "two --backend instances have the label 'hsv'"),
        (
            ['a-b', 'a_b'],
            {'a-b': BackendInstance('a-b', 'hsv'), 'a_b': BackendInstance('a_b', 'null')},
            "'a-b' is written the same",
        ),
        (['a+b'], {'a+b': BackendInstance('a+b', 'hsv')}, "no '+', '=' or '.'"),
    ],
)
def test_a_run_config_of_clashing_or_bad_labels_is_refused_before_anything_is_written(
    tmp_path: Path, backends: list[str], instances: dict[str, BackendInstance], said: str
) -> None:
    out = tmp_path / 'run'
    config = RunConfig(inputs=[RAW], backends=backends, out_dir=out, instances=instances)
    with pytest.raises(UsageError) as caught:
        run_benchmark(config)
    assert said in str(caught.value)
    assert not out.exists()


def test_an_instance_has_the_runs_options_with_its_own_params_on_top() -> None:
    base = BackendOptions(threads=4, conf=0.3, extra={'max_det': '10'})
    (fp32, int8) = parse_instances(
        ['fp32=onnx-cpu', 'int8=onnx-cpu'], ['int8.threads=1', 'int8.max_det=5', 'int8.device=1']
    )
    assert instance_options(base, fp32) is base
    mine = instance_options(base, int8)
    assert (mine.threads, mine.conf, mine.device, dict(mine.extra)) == (1, 0.3, 1, {'max_det': '5'})
    assert int8.params == (('threads', '1'), ('max_det', '5'), ('device', '1'))


def test_a_model_path_may_hold_a_comma_and_other_values_may_not() -> None:
    (inst,) = parse_instances(['a=onnx-cpu'], ['a.model=m,1.onnx'])
    assert with_params(BackendOptions(), inst.params).model == Path('m,1.onnx')
    with pytest.raises(UsageError, match='one value per instance'):
        parse_instances(['a=onnx-cpu'], ['a.conf=0.1,0.2'])
