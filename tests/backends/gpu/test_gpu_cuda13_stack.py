"""One CUDA major across the ``gpu`` extra, the exact libraries the onnxruntime providers link,
and a TensorRT engine cache keyed by everything an engine depends on.

The shared-library loader is faked (``gpufakes.fake_loader``: the names it can load and the
versions they report); the lookups, version decoding and messages are replaybench's.
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import pytest
from backends.gpu.gpufakes import fake_loader

from replaybench.backends.gpu import _libs, availability
from replaybench.backends.gpu.tensorrt import EngineKey, engine_folder, trt_precision

PYPROJECT = Path(__file__).resolve().parents[3] / 'pyproject.toml'
#: The torch releases the GPU code is tested with (docs/gpu.md, Install).
TORCH_RANGE = 'torch>=2.11,<2.14'
CUDA_TOOLKIT_RUNTIME = Path('/usr/local/cuda-13.0/lib/libcudart.so.13')


def _gpu_extra() -> list[str]:
    data = tomllib.loads(PYPROJECT.read_text(encoding='utf-8'))
    return list(data['project']['optional-dependencies']['gpu'])


def test_every_package_of_the_gpu_extra_is_built_for_cuda_13():
    extra = _gpu_extra()
    names = {re.split(r'[\[<>=!~ ]', req, maxsplit=1)[0]: req for req in extra}
    majors = {int(a or b) for req in extra for a, b in re.findall(r'cuda(\d+)x|-cu(\d+)', req)}
    assert majors == {13}
    assert 'cupy-cuda13x' in names
    assert names['onnxruntime-gpu'].startswith('onnxruntime-gpu[cuda,cudnn]>=1.31')
    assert re.fullmatch(r'tensorrt-cu13>=10\.\d+,<11', names['tensorrt-cu13'])
    assert 'nvidia-ml-py' in names
    assert names['torch'] == TORCH_RANGE


def test_the_gpu_extra_accepts_each_torch_it_is_tested_with_and_docs_gpu_md_says_which():
    from packaging.requirements import Requirement

    (torch,) = [Requirement(r) for r in _gpu_extra() if r.startswith('torch')]
    accepted = [
        v for v in ('2.10.0', '2.11.0', '2.12.1', '2.13.0', '2.14.0') if v in torch.specifier
    ]
    assert accepted == ['2.11.0', '2.12.1', '2.13.0']
    docs = (PYPROJECT.parent / 'docs' / 'gpu.md').read_text(encoding='utf-8')
    assert f'"{TORCH_RANGE}"' in docs
    assert 'torch: 2.11, 2.12 and 2.13' in docs


def test_tensorrt_needs_both_exact_sonames_its_provider_links(monkeypatch):
    asked = fake_loader(monkeypatch, {'libnvinfer.so.10': 101300})
    problem = availability.tensorrt_problem()
    assert problem is not None
    assert problem.startswith('TensorRT 10 libraries not found: libnvonnxparser.so.10 ')
    assert 'found libnvinfer.so.10' in problem
    assert "pip install 'tensorrt-cu13>=10.13,<11'" in problem
    assert asked[:2] == ['libnvinfer.so.10', 'libnvonnxparser.so.10']

    fake_loader(monkeypatch, {'libnvinfer.so.10': 101300, 'libnvonnxparser.so.10': None})
    assert availability.tensorrt_problem() is None
    assert availability.tensorrt_library_version() == '10.13.0'


def test_a_tensorrt_of_another_major_is_named_and_not_taken(monkeypatch):
    fake_loader(monkeypatch, {'libnvinfer.so': 110400, 'libnvinfer.so.11': 110400})
    problem = availability.tensorrt_problem() or ''
    assert problem.startswith(
        'TensorRT 10 libraries not found: libnvinfer.so.10, libnvonnxparser.so.10 '
    )
    assert 'found libnvinfer.so (TensorRT 11.4.0), libnvinfer.so.11 (TensorRT 11.4.0)' in problem
    assert availability.tensorrt_availability().ok is False


def test_a_libnvinfer_so_10_that_reports_another_version_is_refused(monkeypatch):
    fake_loader(monkeypatch, {'libnvinfer.so.10': 8601, 'libnvonnxparser.so.10': None})
    assert availability.tensorrt_problem() == (
        'libnvinfer.so.10 reports TensorRT 8.6.1; the provider needs 10.x: pip install '
        "'tensorrt-cu13>=10.13,<11' (see docs/gpu.md)"
    )


def test_a_library_only_in_a_wheel_folder_is_loaded_by_its_path(monkeypatch, tmp_path):
    wheel = tmp_path / 'nvidia' / 'cu13' / 'lib'
    wheel.mkdir(parents=True)
    (wheel / 'libcublas.so.13').write_bytes(b'\x7fELF')
    asked = fake_loader(monkeypatch, {str(wheel / 'libcublas.so.13'): None})
    monkeypatch.setattr(_libs, '_wheel_folders', lambda: [tmp_path / 'nvidia'])
    library = _libs.find_library('libcublas.so.13')
    assert library.where == str(wheel / 'libcublas.so.13')
    assert asked == ['libcublas.so.13', str(wheel / 'libcublas.so.13')]
    _, missing = _libs.load_libraries(_libs.ORT_CUDA_LIBRARIES)
    assert missing == ['libcudart.so.13', 'libcublasLt.so.13', 'libcudnn.so.9']
    assert availability.ort_cuda_library_problem() == (
        "onnxruntime-gpu's CUDA provider links libcudart.so.13, libcublasLt.so.13, "
        'libcudnn.so.9, not found (CUDA 13 / cuDNN 9): pip install '
        "'onnxruntime-gpu[cuda,cudnn]' (see docs/gpu.md)"
    )


@pytest.mark.skipif(not CUDA_TOOLKIT_RUNTIME.is_file(), reason='no CUDA 13 toolkit here')
def test_the_real_cuda_runtime_reports_its_version_without_a_gpu():
    library = _libs.find_library(str(CUDA_TOOLKIT_RUNTIME))
    assert library.found
    assert _libs.version_of(library._replace(name='libcudart.so.13')) == '13.0'


def test_versions_decode_as_tensorrt_and_cudnn_encode_them():
    class Lib:
        def __init__(self, value: int) -> None:
            self.getInferLibVersion = self.cudnnGetVersion = lambda: value

    assert _libs.tensorrt_version(Lib(101300)) == '10.13.0'
    assert _libs.tensorrt_version(Lib(8601)) == '8.6.1'
    assert _libs.cudnn_version(Lib(91002)) == '9.10.2'
    assert _libs.tensorrt_version(Lib(0)) is None


KEY = EngineKey('ab' * 32, '10.13.0', 'Fake GPU A', '8.6', 'fp16', (1, 3, 416, 416))


@pytest.mark.parametrize(
    'change',
    [
        {'model_sha256': 'cd' * 32},
        {'tensorrt': '10.14.1'},
        {'gpu': 'Fake GPU B'},
        {'compute_capability': '8.9'},
        {'precision': 'tf32'},
        {'input_shape': (1, 3, 640, 640)},
    ],
)
def test_each_part_of_the_engine_key_gets_its_own_cache_folder(tmp_path, change):
    other = KEY._replace(**change)
    assert other.digest() != KEY.digest()
    assert engine_folder(tmp_path, other) != engine_folder(tmp_path, KEY)


def test_the_engine_folder_says_what_its_engines_were_built_for(tmp_path):
    folder = engine_folder(tmp_path, KEY)
    assert folder == tmp_path / KEY.digest()
    assert KEY.digest() == EngineKey(*KEY).digest()  # stable across processes: no hash seed
    recorded = json.loads((folder / 'key.json').read_text(encoding='utf-8'))
    assert recorded == {**KEY._asdict(), 'input_shape': [1, 3, 416, 416]}


def test_tensorrt_fp32_is_tf32_on_ampere_unless_the_override_is_set():
    assert trt_precision('fp32', '8.6', {}) == 'tf32'
    assert trt_precision('fp32', '9.0', {'NVIDIA_TF32_OVERRIDE': '1'}) == 'tf32'
    assert trt_precision('fp32', '8.0', {'NVIDIA_TF32_OVERRIDE': '0'}) == 'fp32'
    assert trt_precision('fp32', '7.5', {}) == 'fp32'
    assert trt_precision('fp16', '8.6', {}) == 'fp16'
    assert trt_precision('tf32', '8.6', {}) == 'tf32'
