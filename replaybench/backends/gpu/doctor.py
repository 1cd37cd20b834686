"""``replaybench doctor``: what this machine has for the GPU backends, and what each one needs.

One line per fact: the NVIDIA driver (release, CUDA driver API, the R580 floor of CUDA 13), each
visible GPU, the exact libraries the onnxruntime providers link (CUDA runtime, cuBLAS, cuDNN,
TensorRT), onnxruntime's build and providers, torch's and CuPy's builds, NVML; then each GPU
backend: available or why not, and what it needs. Every package of the ``gpu`` extra is built
for one CUDA major (13): a package built for another is named.

Nothing here raises for a missing piece: it is reported. torch and CuPy are imported to ask
their builds (when installed); onnxruntime is imported to list its providers.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import TYPE_CHECKING, NamedTuple

from replaybench.backends.gpu import _cuda, _libs
from replaybench.backends.gpu.availability import module_missing

if TYPE_CHECKING:
    from replaybench.backends.base import Availability

__all__ = ['BACKEND_NEEDS', 'Finding', 'GpuReport', 'gpu_report']

OK, BAD, INFO = 'ok', 'problem', 'info'

#: What each GPU backend needs, in words (docs/gpu.md says the same).
BACKEND_NEEDS: dict[str, str] = {
    'cuda': (
        f'an NVIDIA GPU, driver R{_cuda.MIN_DRIVER_RELEASE}+, torch built for CUDA '
        f'{_libs.CUDA_MAJOR}; engine ort: onnxruntime-gpu with CUDAExecutionProvider and '
        f'{", ".join(_libs.ORT_CUDA_LIBRARIES)}; engine torch: onnx2torch and onnx'
    ),
    'tensorrt': (
        f'everything engine ort of cuda needs, TensorrtExecutionProvider, and '
        f'{" and ".join(_libs.TENSORRT_LIBRARIES)} (TensorRT {_libs.TENSORRT_MAJOR}.x: '
        f'{_libs.TENSORRT_INSTALL})'
    ),
    'hsv-cuda': (
        f'an NVIDIA GPU, driver R{_cuda.MIN_DRIVER_RELEASE}+, cupy-cuda{_libs.CUDA_MAJOR}x '
        f'(and NVRTC {_libs.CUDA_MAJOR} to compile its kernels)'
    ),
    'cuda-stereo': 'what cuda needs (a stereo model on its engines)',
    'tensorrt-stereo': 'what tensorrt needs (a stereo model on its engine)',
}
_LIBRARY_TOPICS = (
    ('CUDA runtime', _libs.ORT_CUDA_LIBRARIES[0]),
    ('cuBLASLt', _libs.ORT_CUDA_LIBRARIES[1]),
    ('cuBLAS', _libs.ORT_CUDA_LIBRARIES[2]),
    ('cuDNN', _libs.ORT_CUDA_LIBRARIES[3]),
    ('TensorRT', _libs.TENSORRT_LIBRARIES[0]),
    ('TensorRT ONNX parser', _libs.TENSORRT_LIBRARIES[1]),
)
#: Distributions that would bring a second CUDA major or a second onnxruntime.
_WRONG_DISTRIBUTIONS = {
    'cupy-cuda11x': 'CuPy for CUDA 11',
    'cupy-cuda12x': 'CuPy for CUDA 12',
    'tensorrt-cu12': 'TensorRT for CUDA 12',
    'tensorrt-cu11': 'TensorRT for CUDA 11',
}


class Finding(NamedTuple):
    """One line of the report: ``status`` is ``ok``, ``problem`` or ``info``."""

    status: str
    topic: str
    text: str


class GpuReport(NamedTuple):
    """Everything ``replaybench doctor`` prints."""

    findings: tuple[Finding, ...]
    backends: tuple[tuple[str, Availability], ...]

    @property
    def ok(self) -> bool:
        """Every GPU backend can run here."""
        return all(status.ok for _, status in self.backends)

    def lines(self) -> list[str]:
        width = max((len(f.topic) for f in self.findings), default=0)
        out = [f'{f.status:<7}  {f.topic.ljust(width)}  {f.text}' for f in self.findings]
        out.append('')
        for name, status in self.backends:
            state = 'available' if status.ok else f'unavailable: {status.reason}'
            out.append(f'{name}: {state}')
            out.append(f'  needs: {BACKEND_NEEDS[name]}')
        return out


def _distribution(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def _driver() -> list[Finding]:
    problem = _cuda.driver_problem()
    api = _cuda.driver_api_version()
    release = _cuda.nvidia_driver_release()
    if _cuda.load_libcuda() is None:
        return [Finding(BAD, 'driver', problem or 'libcuda not loadable')]
    api_text = f'CUDA driver API {api // 1000}.{api % 1000 // 10}' if api else 'CUDA driver API ?'
    major = release.split('.', 1)[0] if release else ''
    floor = _cuda.MIN_DRIVER_RELEASE
    if major.isdigit():
        too_old = int(major) < floor
    else:  # no NVML: the driver API tells whether CUDA 13 is supported
        too_old = api is None or api < _libs.CUDA_MAJOR * 1000
    text = f'NVIDIA {release or "release unknown (no NVML)"}, {api_text}'
    if too_old:
        text += f': too old, CUDA {_libs.CUDA_MAJOR} needs R{floor} or newer'
    findings = [Finding(BAD if too_old else OK, 'driver', text)]
    if problem is not None:
        findings.append(Finding(BAD, 'GPUs', problem))
        return findings
    count = _cuda.device_count()
    for index in range(count):
        try:
            gpu = _cuda.device_facts(index)
        except Exception as exc:  # noqa: BLE001  a device the driver refuses to describe
            findings.append(Finding(BAD, f'GPU {index}', str(exc)))
            continue
        findings.append(
            Finding(
                INFO,
                f'GPU {index}',
                f'{gpu.name}, compute {gpu.compute_capability}, '
                f'{gpu.total_memory_bytes / (1 << 30):.1f} GiB, PCI {gpu.pci_bus_id}, {gpu.uuid}',
            )
        )
    return findings


def _libraries() -> list[Finding]:
    findings = []
    for topic, name in _LIBRARY_TOPICS:
        library = _libs.find_library(name)
        if not library.found:
            findings.append(Finding(BAD, topic, f'{name} not found'))
            continue
        version = _libs.version_of(library)
        where = 'on the loader path' if library.where == 'loader' else f'in {library.where}'
        shown = f' {version}' if version else ''
        findings.append(Finding(OK, topic, f'{name}{shown} ({where})'))
    for name, version in _libs.other_tensorrt():
        if version is None or not version.startswith(f'{_libs.TENSORRT_MAJOR}.'):
            findings.append(
                Finding(
                    BAD,
                    'TensorRT',
                    f'{name} (TensorRT {version or "?"}) also loads; the provider needs '
                    f'{_libs.TENSORRT_MAJOR}.x',
                )
            )
    return findings


def _onnxruntime() -> list[Finding]:
    cpu, gpu = _distribution('onnxruntime'), _distribution('onnxruntime-gpu')
    findings = []
    if cpu and gpu:
        findings.append(
            Finding(
                BAD,
                'onnxruntime',
                f'both onnxruntime {cpu} and onnxruntime-gpu {gpu} are installed (one module, '
                'whichever was installed last wins): pip uninstall -y onnxruntime '
                'onnxruntime-gpu, then pip install onnxruntime-gpu[cuda,cudnn] (docs/gpu.md)',
            )
        )
    if module_missing('onnxruntime'):
        return [*findings, Finding(BAD, 'onnxruntime', 'not installed')]
    try:
        ort = importlib.import_module('onnxruntime')
        providers = list(ort.get_available_providers())
    except Exception as exc:  # noqa: BLE001  a broken install is a finding
        return [*findings, Finding(BAD, 'onnxruntime', f'{type(exc).__name__}: {exc}')]
    build = _ort_cuda_build()
    cuda = f', built for CUDA {build}' if build else ', a CPU build'
    status = OK if 'CUDAExecutionProvider' in providers else BAD
    if build and not build.startswith(f'{_libs.CUDA_MAJOR}.'):
        status = BAD
        cuda += f' (the gpu extra is CUDA {_libs.CUDA_MAJOR})'
    findings.append(
        Finding(
            status,
            'onnxruntime',
            f'{getattr(ort, "__version__", "?")}{cuda}; providers: {", ".join(providers)}',
        )
    )
    return findings


def _ort_cuda_build() -> str:
    try:
        info = importlib.import_module('onnxruntime.capi.build_and_package_info')
    except Exception:  # noqa: BLE001  older builds have no such module
        return ''
    return str(getattr(info, 'cuda_version', '') or '')


def _torch() -> list[Finding]:
    if module_missing('torch'):
        return [Finding(BAD, 'torch', 'not installed')]
    try:
        torch = importlib.import_module('torch')
        cuda = torch.version.cuda
        available = bool(torch.cuda.is_available())
        cudnn = torch.backends.cudnn.version() if available else None
    except Exception as exc:  # noqa: BLE001  a broken install is a finding
        return [Finding(BAD, 'torch', f'{type(exc).__name__}: {exc}')]
    if cuda is None:
        return [Finding(BAD, 'torch', f'{torch.__version__}: a CPU-only build')]
    text = f'{torch.__version__}, built for CUDA {cuda}'
    text += f', cuDNN {cudnn}' if cudnn else ''
    text += ', CUDA usable' if available else ', CUDA not usable (torch.cuda.is_available() False)'
    good = available and str(cuda).startswith(f'{_libs.CUDA_MAJOR}.')
    if not str(cuda).startswith(f'{_libs.CUDA_MAJOR}.'):
        text += f' (the gpu extra is CUDA {_libs.CUDA_MAJOR})'
    return [Finding(OK if good else BAD, 'torch', text)]


def _cupy() -> list[Finding]:
    wanted = f'cupy-cuda{_libs.CUDA_MAJOR}x'
    version = _distribution(wanted)
    if module_missing('cupy'):
        return [Finding(BAD, 'CuPy', f'not installed ({wanted})')]
    if version is None:
        return [Finding(BAD, 'CuPy', f'installed, but not as {wanted}')]
    try:
        cupy = importlib.import_module('cupy')
        runtime = int(cupy.cuda.runtime.runtimeGetVersion())
        count = int(cupy.cuda.runtime.getDeviceCount())
    except Exception as exc:  # noqa: BLE001  missing CUDA libraries and the like
        return [Finding(BAD, 'CuPy', f'{wanted} {version}: {type(exc).__name__}: {exc}')]
    text = f'{wanted} {version}, CUDA runtime {runtime // 1000}.{runtime % 1000 // 10}, '
    return [Finding(OK, 'CuPy', f'{text}{count} GPU(s)')]


def _packages() -> list[Finding]:
    findings = []
    for name, what in _WRONG_DISTRIBUTIONS.items():
        version = _distribution(name)
        if version is not None:
            findings.append(
                Finding(
                    BAD,
                    'packages',
                    f'{name} {version} ({what}) is installed: the gpu extra is CUDA '
                    f'{_libs.CUDA_MAJOR} only; pip uninstall {name}',
                )
            )
    nvml = _distribution('nvidia-ml-py')
    findings.append(
        Finding(OK, 'NVML', f'nvidia-ml-py {nvml}')
        if nvml
        else Finding(BAD, 'NVML', 'nvidia-ml-py not installed: no GPU utilisation or power')
    )
    for name in ('onnx2torch', 'onnx'):
        version = _distribution(name)
        findings.append(
            Finding(INFO, name, version if version else 'not installed (engine torch needs it)')
        )
    return findings


def gpu_report() -> GpuReport:
    """Collect every finding and each GPU backend's availability."""
    from replaybench.backends import get_backend

    findings = [*_driver(), *_libraries(), *_onnxruntime(), *_torch(), *_cupy(), *_packages()]
    backends = tuple((name, get_backend(name).available()) for name in BACKEND_NEEDS)
    return GpuReport(tuple(findings), backends)
