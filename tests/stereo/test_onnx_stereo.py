"""The onnx-stereo backend: the bundled model on the stereo fixtures, layouts, bad models."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from replaybench.backends import get_backend
from replaybench.backends.base import BackendOptions
from replaybench.backends.onnx_stereo import OnnxStereoBackend
from replaybench.errors import BackendError
from replaybench.stereo import Disparity
from replaybench.types import Frame, FrameSet

pytest.importorskip('onnxruntime')
onnx = pytest.importorskip('onnx')

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from replaybench.fixtures.stereo import write_stereo_mcap

    out = tmp_path_factory.mktemp('stereobags')
    write_stereo_mcap(out / 'stereo.mcap', frames=3)
    write_stereo_mcap(out / 'stereo_raw.mcap', frames=3, raw=True)
    return out


def test_onnx_stereo_is_registered_as_a_stereo_backend_of_frame_sets() -> None:
    assert get_backend('onnx-stereo') is OnnxStereoBackend  # type: ignore[comparison-overlap]
    assert OnnxStereoBackend.task == 'stereo'
    assert OnnxStereoBackend.takes_frame_sets
    assert OnnxStereoBackend.reads_camera_info


def _rectified_set(left: np.ndarray, right: np.ndarray, encoding: str = 'mono8') -> FrameSet:
    from replaybench.fixtures.stereo import rectified_camera_infos

    height, width = left.shape[:2]
    infos = rectified_camera_infos((width, height), 0)
    return FrameSet(
        tuple(
            Frame(
                f'/s/{side}/image_rect',
                0,
                0,
                0,
                info.frame_id,
                img,
                encoding,
                encoding,
                False,
                info,
            )
            for side, img, info in zip(('left', 'right'), (left, right), infos, strict=True)
        )
    )


def _tiny_model(
    path: Path, layout: str, channels: int, size: tuple[int, int], shift: float
) -> Path:
    """A model whose disparity is the mean of its left input's channels times 0 plus
    ``shift`` (a constant in the network's pixels): its output is known exactly."""
    from onnx import TensorProto, helper

    width, height = size
    if layout == 'two-inputs':
        inputs = [
            helper.make_tensor_value_info(n, TensorProto.FLOAT, [1, channels, height, width])
            for n in ('right', 'left')  # named, in the other order
        ]
        first = 'left'
    else:
        inputs = [
            helper.make_tensor_value_info(
                'pair', TensorProto.FLOAT, [1, 2 * channels, height, width]
            )
        ]
        first = 'pair'
    nodes = [
        helper.make_node('ReduceMean', [first], ['mean'], axes=[1], keepdims=1),
        helper.make_node('Mul', ['mean', 'zero'], ['zeroed']),
        helper.make_node('Add', ['zeroed', 'shift'], ['disparity']),
    ]
    graph = helper.make_graph(
        nodes,
        'tiny',
        inputs,
        [helper.make_tensor_value_info('disparity', TensorProto.FLOAT, [1, 1, height, width])],
        initializer=[
            helper.make_tensor('zero', TensorProto.FLOAT, [], [0.0]),
            helper.make_tensor('shift', TensorProto.FLOAT, [], [shift]),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', 13)])
    model.ir_version = 8
    path.write_bytes(model.SerializeToString())
    return path


@pytest.mark.parametrize(
    ('layout', 'channels'), [('two-inputs', 1), ('two-inputs', 3), ('six-channel', 3)]
)
def test_the_layout_is_found_from_the_input_shapes_and_the_output_rescaled(
    tmp_path: Path, layout: str, channels: int
) -> None:
    model = _tiny_model(tmp_path / 'tiny.onnx', layout, channels, (80, 60), 5.0)
    backend = OnnxStereoBackend(BackendOptions(model=model, threads=1))
    left = np.random.default_rng(0).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    out = backend.detect(_rectified_set(left, left, 'bgr8')).output
    assert isinstance(out, Disparity)
    assert backend.info()['layout'] == layout
    assert backend.info()['layout_source'] == 'input shapes'
    assert backend.info()['channel_order'] == ('grey' if channels == 1 else 'rgb')
    assert out.disparity.shape == (240, 320)
    # 5 px at 80 wide is 20 px at 320 wide
    np.testing.assert_allclose(out.disparity, 20.0)
    assert out.max_disparity == pytest.approx(80 / 4 * 4)


def test_model_family_forces_the_layout_and_a_wrong_one_is_one_line(tmp_path: Path) -> None:
    model = _tiny_model(tmp_path / 'tiny.onnx', 'six-channel', 3, (80, 60), 1.0)
    with pytest.raises(BackendError, match='layout two-inputs needs two inputs, the model has 1'):
        OnnxStereoBackend(BackendOptions(model=model, model_family='two-inputs')).open()
    with pytest.raises(BackendError, match="--model-family 'yolov8' is no stereo layout"):
        OnnxStereoBackend(BackendOptions(model=model, model_family='yolov8'))


def _five_channel_model(tmp_path: Path) -> Path:
    from onnx import TensorProto, helper

    inp = helper.make_tensor_value_info('x', TensorProto.FLOAT, [1, 5, 8, 8])
    out = helper.make_tensor_value_info('y', TensorProto.FLOAT, [1, 1, 8, 8])
    node = helper.make_node('ReduceMean', ['x'], ['y'], axes=[1], keepdims=1)
    model = helper.make_model(
        helper.make_graph([node], 'five', [inp], [out]), opset_imports=[helper.make_opsetid('', 13)]
    )
    model.ir_version = 8
    path = tmp_path / 'five.onnx'
    path.write_bytes(model.SerializeToString())
    return path


def test_a_model_that_is_no_stereo_model_is_refused_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(BackendError, match='has 5 channels') as err:
        OnnxStereoBackend(BackendOptions(model=_five_channel_model(tmp_path))).open()
    assert '\n' not in str(err.value)
    with pytest.raises(BackendError, match='has 3 channels; layout six-channel'):
        OnnxStereoBackend(BackendOptions(model=REPO / 'replaybench/models/blobs.onnx')).open()
    garbage = tmp_path / 'garbage.onnx'
    garbage.write_bytes(b'not a model')
    with pytest.raises(BackendError, match='cannot load') as err:
        OnnxStereoBackend(BackendOptions(model=garbage)).open()
    assert '\n' not in str(err.value)


def test_a_bad_model_on_the_command_line_is_one_line_and_exit_2(tmp_path: Path, bags: Path) -> None:
    garbage = tmp_path / 'garbage.onnx'
    garbage.write_bytes(b'not a model')
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bags / 'stereo.mcap'),
            '--backend',
            'onnx-stereo',
            '--model',
            str(garbage),
            '--sync',
            'exact',
        ],
        capture_output=True,
        text=True,
        check=False,
        cwd=tmp_path,
    )
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr
    assert 'onnx-stereo' in lines[0]
    assert 'garbage.onnx' in lines[0]
