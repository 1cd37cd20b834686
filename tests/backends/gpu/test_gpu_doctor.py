"""``replaybench doctor``: the driver, the exact libraries, the builds, and what each GPU backend
needs, one line each; exit status 0 only when every GPU backend can run.

The CUDA driver (``FakeLibcuda``) and the shared-library loader (``fake_loader``) are stood in
for; onnxruntime, torch and the installed distributions are this machine's own (a CPU-only
torch and onnxruntime here), plus a real dist-info folder for a package of the wrong CUDA major.
"""

from __future__ import annotations

import sys

import pytest
from backends.gpu.gpufakes import GPU_A, GPU_B, fake_loader
from typer.testing import CliRunner

from replaybench.backends.gpu.doctor import BACKEND_NEEDS, gpu_report
from replaybench.cli import app

runner = CliRunner()
ALL_LIBRARIES = {
    'libcudart.so.13': 13000,
    'libcublasLt.so.13': None,
    'libcublas.so.13': None,
    'libcudnn.so.9': 91002,
    'libnvinfer.so.10': 101300,
    'libnvonnxparser.so.10': None,
}


def _lines(report) -> dict[str, str]:
    found: dict[str, str] = {}
    for line in report.lines():
        status, _, rest = line.partition('  ')
        topic = rest.strip().split('  ', 1)[0]
        if status.strip() in ('ok', 'problem', 'info'):
            found.setdefault(topic, line)
    return found


def test_a_r580_driver_with_every_library_is_reported_ok(monkeypatch, driver):
    driver([GPU_A, GPU_B], release='580.65.06')
    fake_loader(monkeypatch, ALL_LIBRARIES)
    lines = _lines(gpu_report())
    assert lines['driver'].startswith('ok ')
    assert 'NVIDIA 580.65.06, CUDA driver API 13.0' in lines['driver']
    assert 'Fake GPU A, compute 8.6, 24.0 GiB, PCI 0000:17:00.0, GPU-00010203-' in lines['GPU 0']
    assert 'Fake GPU B, compute 9.0, 80.0 GiB, PCI 0000:65:00.0' in lines['GPU 1']
    assert lines['CUDA runtime'].endswith('libcudart.so.13 13.0 (on the loader path)')
    assert lines['cuDNN'].endswith('libcudnn.so.9 9.10.2 (on the loader path)')
    assert lines['TensorRT'].endswith('libnvinfer.so.10 10.13.0 (on the loader path)')
    assert lines['TensorRT ONNX parser'].startswith('ok ')


def test_an_old_driver_and_a_tensorrt_11_are_named_as_problems(monkeypatch, driver):
    driver([GPU_A], version=12080, release='550.54.15')
    fake_loader(monkeypatch, {'libnvinfer.so.11': 110400})
    report = gpu_report()
    lines = _lines(report)
    assert lines['driver'].startswith('problem ')
    assert lines['driver'].endswith('too old, CUDA 13 needs R580 or newer')
    assert lines['TensorRT'].startswith('problem ')
    text = '\n'.join(report.lines())
    assert 'libnvinfer.so.11 (TensorRT 11.4.0) also loads; the provider needs 10.x' in text
    assert 'libnvonnxparser.so.10 not found' in text
    assert report.ok is False


def test_each_gpu_backend_says_whether_it_runs_and_what_it_needs(monkeypatch, driver):
    driver([])
    fake_loader(monkeypatch, {})
    report = gpu_report()
    names = [name for name, _ in report.backends]
    assert names == ['cuda', 'tensorrt', 'hsv-cuda', 'cuda-stereo', 'tensorrt-stereo']
    text = report.lines()
    for name, status in report.backends:
        assert not status.ok
        assert f'{name}: unavailable: {status.reason}' in text
        assert f'  needs: {BACKEND_NEEDS[name]}' in text
    assert 'libnvinfer.so.10 and libnvonnxparser.so.10' in BACKEND_NEEDS['tensorrt']
    assert 'cupy-cuda13x' in BACKEND_NEEDS['hsv-cuda']
    assert 'R580+' in BACKEND_NEEDS['cuda']


def test_a_package_for_another_cuda_major_is_named(monkeypatch, tmp_path, driver):
    driver([GPU_A], release='580.65.06')
    fake_loader(monkeypatch, {})
    info = tmp_path / 'cupy_cuda12x-13.6.0.dist-info'
    info.mkdir()
    (info / 'METADATA').write_text(
        'Metadata-Version: 2.1\nName: cupy-cuda12x\nVersion: 13.6.0\n', encoding='utf-8'
    )
    monkeypatch.setattr(sys, 'path', [str(tmp_path), *sys.path])
    text = '\n'.join(gpu_report().lines())
    assert 'cupy-cuda12x 13.6.0 (CuPy for CUDA 12) is installed: the gpu extra is CUDA 13 only' in (
        text
    )


def test_the_doctor_command_prints_the_report_and_exits_1_when_a_backend_cannot_run(
    monkeypatch, driver
):
    driver([GPU_A], release='580.65.06')
    fake_loader(monkeypatch, ALL_LIBRARIES)
    result = runner.invoke(app, ['doctor'])
    assert result.exit_code == 1, result.output
    assert 'NVIDIA 580.65.06' in result.output
    assert 'hsv-cuda: unavailable: ' in result.output
    assert 'Traceback' not in result.output


@pytest.mark.parametrize('args', [['doctor', '--help']])
def test_the_doctor_command_documents_its_exit_status(args):
    result = runner.invoke(app, args)
    assert result.exit_code == 0
    assert 'Exit status 0 when every GPU backend can run here, 1 when one cannot.' in ' '.join(
        result.output.split()
    )
