"""``tensorrt --precision int8`` on the CPU side: the calibration cache from a bag's frames.

TensorRT's classes (``IInt8EntropyCalibrator2``, the builder, the ONNX parser) are stood in for
by a module that drives the calibrator as TensorRT's builder does (``get_batch`` until None,
then ``write_calibration_cache``); torch is the real CPU build (``torch_on_the_cpu``), and the
frames are the real fixture bag's, through the real letterbox. onnxruntime's session is the
fake GPU build of ``gpufakes`` (its TensorRT provider cannot load here), so what is checked is
what the provider is asked for.
"""

from __future__ import annotations

import sys
import types
from pathlib import Path

import numpy as np
import pytest
from backends.gpu.gpufakes import GPU_A, fake_gpu_build, fake_loader, torch_on_the_cpu

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu._int8 import CACHE_NAME, calibration_batches, entropy_calibrator
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.tensorrt import TensorrtBackend
from replaybench.detector.calibration import calibration_frames
from replaybench.errors import BackendError, BackendUnavailableError

REPO = Path(__file__).resolve().parents[3]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
CACHE_BYTES = b'TRT-101300-EntropyCalibration2\nimages: 3c010a14\n'


def _fake_tensorrt(seen: list[np.ndarray]) -> types.ModuleType:
    trt = types.ModuleType('tensorrt')

    class IInt8EntropyCalibrator2:
        def __init__(self) -> None:
            pass

    class Logger:
        WARNING = 2

        def __init__(self, level: int) -> None:
            self.level = level

    class Config:
        def __init__(self) -> None:
            self.flags: list[str] = []
            self.int8_calibrator = None

        def set_flag(self, flag: str) -> None:
            self.flags.append(flag)

    class Builder:
        def __init__(self, logger: Logger) -> None:
            self.logger = logger

        def create_network(self, flags: int) -> object:
            return object()

        def create_builder_config(self) -> Config:
            return Config()

        def build_serialized_network(self, network: object, config: Config) -> bytes:
            assert 'INT8' in config.flags
            calibrator = config.int8_calibrator
            assert calibrator is not None
            assert calibrator.get_batch_size() == 1
            assert calibrator.read_calibration_cache() is None
            while (pointers := calibrator.get_batch(['images'])) is not None:
                tensor = calibrator.device_input
                assert pointers == [tensor.data_ptr()]
                seen.append(tensor.numpy().copy())
            calibrator.write_calibration_cache(memoryview(CACHE_BYTES))
            return b'engine'

    class OnnxParser:
        num_errors = 0

        def __init__(self, network: object, logger: Logger) -> None:
            pass

        def parse(self, data: bytes) -> bool:
            return data[:1] != b''

    trt.IInt8EntropyCalibrator2 = IInt8EntropyCalibrator2  # type: ignore[attr-defined]
    trt.Logger = Logger  # type: ignore[attr-defined]
    trt.Builder = Builder  # type: ignore[attr-defined]
    trt.OnnxParser = OnnxParser  # type: ignore[attr-defined]
    trt.BuilderFlag = types.SimpleNamespace(INT8='INT8')  # type: ignore[attr-defined]
    return trt


def _install_gpu(monkeypatch, driver):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    fake_loader(monkeypatch, {'libnvinfer.so.10': 101300, 'libnvonnxparser.so.10': None})
    return fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])


@pytest.fixture
def gpu(monkeypatch, driver):
    return _install_gpu(monkeypatch, driver)


def test_int8_calibrates_on_the_bags_frames_and_hands_the_cache_to_tensorrt(
    monkeypatch, gpu, tiny_model, tmp_path
) -> None:
    fed: list[np.ndarray] = []
    monkeypatch.setitem(sys.modules, 'tensorrt', _fake_tensorrt(fed))
    extra = {'trt_cache': str(tmp_path / 'engines'), 'calibration_bag': str(RAW)}
    extra['calibration_frames'] = '4'
    backend = TensorrtBackend(BackendOptions(model=tiny_model, precision='int8', extra=extra))
    with pytest.raises(BackendUnavailableError, match='did not enable TensorrtExecutionProvider'):
        backend.open()  # the fake build's session has no TensorRT provider
    # the calibrator was fed the frames quantize would take, letterboxed as the model wants
    assert [f.seq for f in calibration_frames(RAW, 4).frames] == [0, 3, 6, 9]
    assert len(fed) == 4
    assert all(t.shape == (1, 3, 32, 64) and t.dtype == np.float32 for t in fed)
    assert backend.spec is None or backend.spec.preprocess.size == (64, 32)
    assert not np.array_equal(fed[0], fed[3])
    assert backend.engine_key is not None
    folder = tmp_path / 'engines' / backend.engine_key.digest()
    assert (folder / CACHE_NAME).read_bytes() == CACHE_BYTES
    assert backend.engine_key.precision == 'int8'
    assert backend.engine_key.calibration.endswith(':4')
    (_, trt), _ = gpu.providers[-1]
    assert trt['trt_int8_enable'] is True
    assert trt['trt_int8_calibration_table_name'] == CACHE_NAME
    assert trt['trt_int8_use_native_calibration_table'] is True
    assert trt['trt_fp16_enable'] is False


def test_the_calibrator_gives_its_batches_in_order_then_none_and_reads_its_cache(tmp_path):
    torch = pytest.importorskip('torch')
    trt = _fake_tensorrt([])
    batches = [np.full((1, 3, 2, 2), i, np.float32) for i in range(3)]
    cache = tmp_path / 'c.cache'
    calibrator = entropy_calibrator(trt, torch, batches, cache, torch.device('cpu'))
    values = []
    while calibrator.get_batch(['images']) is not None:
        values.append(float(calibrator.device_input[0, 0, 0, 0]))
    assert values == [0.0, 1.0, 2.0]
    assert calibrator.read_calibration_cache() is None
    calibrator.write_calibration_cache(b'abc')
    assert calibrator.read_calibration_cache() == b'abc'


@pytest.mark.usefixtures('gpu')
def test_a_cached_calibration_is_used_again_without_calibrating(
    monkeypatch, tiny_model, tmp_path
) -> None:
    fed: list[np.ndarray] = []
    monkeypatch.setitem(sys.modules, 'tensorrt', _fake_tensorrt(fed))
    extra = {'trt_cache': str(tmp_path / 'engines'), 'calibration_bag': str(RAW)}
    for _ in range(2):
        backend = TensorrtBackend(BackendOptions(model=tiny_model, precision='int8', extra=extra))
        with pytest.raises(BackendUnavailableError):
            backend.open()
    assert len(fed) == 10  # rgb8_raw.mcap's 10 frames, once


def test_a_quantized_model_runs_int8_with_its_own_scales_and_no_cache(
    monkeypatch, driver, tiny_model, tmp_path
) -> None:
    onnx = pytest.importorskip('onnx')
    from replaybench.app.quantize import QuantizeSettings, quantize_model

    out = tmp_path / 'tiny.int8.onnx'
    quantize_model(QuantizeSettings(model=tiny_model, bag=RAW, out=out, frames=2, exclude=()))
    assert any(n.op_type == 'QuantizeLinear' for n in onnx.load(str(out)).graph.node)
    gpu = _install_gpu(monkeypatch, driver)
    monkeypatch.setitem(sys.modules, 'tensorrt', None)  # never imported for a QDQ model
    extra = {'trt_cache': str(tmp_path / 'engines')}
    backend = TensorrtBackend(BackendOptions(model=out, precision='int8', extra=extra))
    with pytest.raises(BackendUnavailableError, match='did not enable'):
        backend.open()
    assert backend.engine_key is not None
    assert backend.engine_key.calibration == 'qdq'
    (_, trt), _ = gpu.providers[-1]
    assert trt['trt_int8_enable'] is True
    assert 'trt_int8_calibration_table_name' not in trt


@pytest.mark.usefixtures('gpu')
def test_int8_of_a_float_model_without_a_calibration_bag_is_one_line(tiny_model, tmp_path):
    extra = {'trt_cache': str(tmp_path / 'engines')}
    backend = TensorrtBackend(BackendOptions(model=tiny_model, precision='int8', extra=extra))
    with pytest.raises(BackendError, match='needs a model from replaybench quantize'):
        backend.open()


def test_only_tensorrt_takes_precision_int8() -> None:
    with pytest.raises(BackendError, match="--precision int8 is the tensorrt backend's"):
        CudaBackend(BackendOptions(precision='int8'))


def test_calibration_batches_are_the_letterboxed_frames(tiny_model) -> None:
    from replaybench.detector.spec import load_model_spec

    spec = load_model_spec(tiny_model)
    batches = calibration_batches(spec, RAW, 2)
    assert [b.shape for b in batches] == [(1, 3, 32, 64)] * 2
    assert float(batches[0].min()) >= 0.0
    assert float(batches[0].max()) <= 1.0


@pytest.mark.usefixtures('gpu')
def test_a_calibration_holdout_keeps_its_frames_out_and_is_part_of_the_cache_key(
    monkeypatch, tiny_model, tmp_path
) -> None:
    fed: list[np.ndarray] = []
    monkeypatch.setitem(sys.modules, 'tensorrt', _fake_tensorrt(fed))
    extra = {
        'trt_cache': str(tmp_path / 'engines'),
        'calibration_bag': str(RAW),
        'calibration_frames': '4',
        'calibration_holdout': '0:0.2',
    }
    backend = TensorrtBackend(BackendOptions(model=tiny_model, precision='int8', extra=extra))
    with pytest.raises(BackendUnavailableError, match='did not enable TensorrtExecutionProvider'):
        backend.open()
    held = calibration_frames(RAW, 4, holdout=((0.0, 0.2),))
    assert all(f.seq not in {0, 1, 2, 3, 4, 5} for f in held.frames)  # 0.2 s of 30 Hz
    from replaybench.detector.spec import load_model_spec

    expected = calibration_batches(load_model_spec(tiny_model), RAW, 4, ((0.0, 0.2),))
    assert len(fed) == len(expected) == 4
    assert all(np.array_equal(a, b) for a, b in zip(fed, expected, strict=True))
    assert backend.engine_key is not None
    assert backend.engine_key.calibration.endswith(':4:0-0.2')


def test_a_malformed_calibration_holdout_is_one_line(tiny_model) -> None:
    extra = {'calibration_bag': str(RAW), 'calibration_holdout': '5'}
    backend = TensorrtBackend(BackendOptions(model=tiny_model, precision='int8', extra=extra))
    with pytest.raises(BackendError, match=r"^tensorrt: calibration_holdout '5': expected START"):
        backend._calibration_holdout()
