"""fp32 means fp32: TF32 is off in torch (matmul and cuDNN convolutions) and in onnxruntime's CUDA
provider unless ``--precision tf32`` asks for it; run.json says which precision ran.

torch's precision flags are real (they exist in CPU builds too); only torch's CUDA calls and
onnxruntime's GPU build are stood in for (``gpufakes``).
"""

from __future__ import annotations

import importlib.util

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


def test_precisions_are_fp32_tf32_and_fp16_and_nothing_else():
    assert PRECISIONS == ('fp32', 'tf32', 'fp16')
    with pytest.raises(BackendError, match=r"unknown --precision 'bf16'; known: fp32, tf32, fp16"):
        CudaBackend(BackendOptions(precision='bf16'))
