"""fp32 means fp32: TF32 is off in torch (matmul and cuDNN convolutions) and in onnxruntime's CUDA
provider unless ``--precision tf32`` asks for it; run.json says which precision ran.

torch's precision flags are real (they exist in CPU builds too); only torch's CUDA calls and
onnxruntime's GPU build are stood in for (``gpufakes``).
"""

from __future__ import annotations

import importlib.util
from typing import Any

import pytest
from backends.gpu.gpufakes import GPU_A, fake_gpu_build, torch_on_the_cpu

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu.cuda import PRECISIONS, CudaBackend, set_tf32
from replaybench.errors import BackendError

torch = pytest.importorskip('torch')
GPU_SESSION = ['CUDAExecutionProvider', 'CPUExecutionProvider']


def _flags() -> tuple[str, str]:
    return torch.backends.cuda.matmul.fp32_precision, torch.backends.cudnn.conv.fp32_precision


def test_tf32_is_switched_off_and_back_as_it_was():
    before = _flags()
    restore = set_tf32(torch, allow=False)
    assert _flags() == ('ieee', 'ieee')
    restore()
    assert _flags() == before
    restore = set_tf32(torch, allow=True)
    assert _flags() == ('tf32', 'tf32')
    restore()
    assert _flags() == before


@pytest.mark.parametrize(
    ('precision', 'mode', 'use_tf32'), [('fp32', 'ieee', 0), ('tf32', 'tf32', 1)]
)
def test_the_requested_precision_holds_while_the_backend_is_open(
    monkeypatch, tiny_model, driver, precision, mode, use_tf32
):
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    seen = fake_gpu_build(monkeypatch, GPU_SESSION)
    before = _flags()
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort', precision=precision))
    backend.open()
    during = _flags()
    info = backend.info()
    backend.close()
    assert during == (mode, mode)
    assert _flags() == before
    assert seen.providers[0][0][1]['use_tf32'] == use_tf32
    assert info['precision'] == precision
    assert info['precision_requested'] == precision
    assert info['tf32'] is (precision == 'tf32')


def test_the_torch_engine_runs_its_convolutions_without_tf32(monkeypatch, driver):
    from replaybench.detector.spec import DEFAULT_MODEL

    if not DEFAULT_MODEL.is_file():
        pytest.skip(f'{DEFAULT_MODEL} is not installed')
    if importlib.util.find_spec('onnx2torch') is None:
        pytest.skip('onnx2torch is not installed (make install)')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    seen: list[str] = []
    real_conv = torch.nn.functional.conv2d

    def conv2d(*args, **kwargs):
        seen.append(torch.backends.cudnn.conv.fp32_precision)
        return real_conv(*args, **kwargs)

    monkeypatch.setattr(torch.nn.functional, 'conv2d', conv2d)
    backend = CudaBackend(BackendOptions(model=DEFAULT_MODEL, engine='torch'))
    backend.open()
    backend.close()
    assert seen  # the warm-up ran the converted model's convolutions
    assert set(seen) == {'ieee'}


def test_precisions_are_fp32_tf32_fp16_and_int8_and_nothing_else():
    assert PRECISIONS == ('fp32', 'tf32', 'fp16', 'int8')
    with pytest.raises(
        BackendError, match=r"unknown --precision 'bf16'; known: fp32, tf32, fp16, int8"
    ):
        CudaBackend(BackendOptions(precision='bf16'))


def _legacy() -> tuple[bool, bool]:
    return torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32


@pytest.mark.parametrize(('allow', 'mode'), [(False, 'ieee'), (True, 'tf32')])
def test_the_legacy_tf32_flags_read_the_same_as_the_new_modes(allow, mode):
    # conv alone set to 'ieee' makes reading cudnn.allow_tf32 raise in torch >= 2.9
    restore = set_tf32(torch, allow=allow)
    try:
        assert _flags() == (mode, mode)
        assert torch.backends.cudnn.rnn.fp32_precision == mode
        assert _legacy() == (allow, allow)
    finally:
        restore()


def test_a_process_whose_flags_already_disagree_gets_them_back_as_they_were():
    restore_outer = set_tf32(torch, allow=True)
    torch.backends.cudnn.conv.fp32_precision = 'ieee'  # conv and RNN now disagree
    before = (_flags(), torch.backends.cudnn.rnn.fp32_precision)
    restore = set_tf32(torch, allow=False)
    assert _legacy() == (False, False)
    restore()
    assert (_flags(), torch.backends.cudnn.rnn.fp32_precision) == before
    restore_outer()


def _record_flags_per_frame(backend: CudaBackend, seen: list[tuple[str, str]]) -> None:
    engine = backend._engine
    assert engine is not None

    def run() -> Any:
        seen.append(_flags())
        return engine()

    backend._engine = run  # type: ignore[assignment]


def test_two_open_engines_each_run_in_their_own_mode_and_the_first_closing_keeps_the_other(
    monkeypatch, tiny_model, driver, scene
):
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    fake_gpu_build(monkeypatch, GPU_SESSION)
    before = _flags()
    strict = CudaBackend(BackendOptions(model=tiny_model, engine='ort', precision='fp32'))
    loose = CudaBackend(BackendOptions(model=tiny_model, engine='ort', precision='tf32'))
    strict.open()
    loose.open()  # every backend is opened before the first pass
    seen: list[tuple[str, str]] = []
    _record_flags_per_frame(strict, seen)
    _record_flags_per_frame(loose, seen)
    frame = scene(seed=1).frame('bgr8')
    strict.detect(frame)
    strict.close()
    loose.detect(frame)
    during = _flags()
    loose.close()
    assert seen == [('ieee', 'ieee'), ('tf32', 'tf32')]
    assert during == ('tf32', 'tf32')
    assert _flags() == before
