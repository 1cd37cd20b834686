"""Cheap, honest answers to "can this GPU backend run here, and if not, why not?".

Module presence is checked with ``importlib.util.find_spec`` and the GPU with the CUDA driver
(``libcuda``) before anything heavy is imported: torch and CuPy are imported only once a GPU
is known to be there. onnxruntime (a core dependency) is imported to list its providers.

Every problem found is reported, joined by ``'; '``, so that one ``replaybench backends``
tells everything that is missing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import importlib.util
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.backends.base import Availability
from replaybench.backends.gpu._cuda import driver_problem
from replaybench.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    'GPU_EXTRA',
    'check_session_providers',
    'cuda_availability',
    'cupy_problem',
    'hsv_cuda_availability',
    'module_missing',
    'ort_provider_problem',
    'tensorrt_availability',
    'tensorrt_problem',
    'torch_problem',
]

GPU_EXTRA = "pip install 'replaybench[gpu]'"
_DOCS = 'see docs/gpu.md'


def module_missing(name: str) -> bool:
    """Whether ``name`` cannot be imported (checked without importing it)."""
    try:
        return importlib.util.find_spec(name) is None
    except (ImportError, ValueError):
        return True


def ort_provider_problem(provider: str) -> str | None:
    """Why onnxruntime lacks ``provider``, or None when its build has it.

    The list only says what the build contains: onnxruntime-gpu lists the CUDA and TensorRT
    providers even without a GPU, so a session's own providers must be checked after creating
    it (``check_session_providers``).
    """
    if module_missing('onnxruntime'):
        return 'onnxruntime is not installed: install onnxruntime-gpu (see docs/gpu.md)'
    try:
        import onnxruntime as ort

        available = list(ort.get_available_providers())
        version = str(getattr(ort, '__version__', '?'))
    except Exception as exc:  # a broken install is a reason, not a crash
        return f'onnxruntime cannot be imported: {type(exc).__name__}: {exc}'
    if provider not in available:
        return (
            f'onnxruntime {version} has no {provider}: install onnxruntime-gpu in place of '
            f'onnxruntime ({_DOCS})'
        )
    return None


def torch_problem(device: int | None = None) -> str | None:
    """Why torch cannot use CUDA (device ``device``), or None. Imports torch when installed."""
    if module_missing('torch'):
        return f'torch is not installed: {GPU_EXTRA}'
    try:
        torch = importlib.import_module('torch')
    except Exception as exc:  # a broken install is a reason, not a crash
        return f'torch cannot be imported: {type(exc).__name__}: {exc}'
    if torch.version.cuda is None:
        return f'torch {torch.__version__} is a CPU-only build: install a CUDA build ({_DOCS})'
    if not torch.cuda.is_available():
        return f'torch {torch.__version__} cannot use CUDA (torch.cuda.is_available() is False)'
    count = torch.cuda.device_count()
    if device is not None and not 0 <= device < count:
        return f'torch sees no GPU with index {device} ({count} visible)'
    return None


def cupy_problem(device: int | None = None) -> str | None:
    """Why CuPy cannot use the GPU, or None. Imports CuPy when installed."""
    if module_missing('cupy'):
        return f'cupy not installed: {GPU_EXTRA}'
    try:
        cupy = importlib.import_module('cupy')
        count = int(cupy.cuda.runtime.getDeviceCount())
    except Exception as exc:  # missing CUDA runtime libraries and the like
        return f'cupy cannot use CUDA: {type(exc).__name__}: {exc}'
    if device is not None and not 0 <= device < count:
        return f'cupy sees no GPU with index {device} ({count} visible)'
    return None


def _tensorrt_candidates() -> list[str]:
    if sys.platform == 'win32':
        return ['nvinfer_10.dll', 'nvinfer.dll']
    names = ['libnvinfer.so.10', 'libnvinfer.so']
    found = ctypes.util.find_library('nvinfer')
    if found and found not in names:
        names.append(found)
    return names


def _wheel_folder(module: str) -> str | None:
    """The folder of an installed package, found without importing it."""
    if module_missing(module):
        return None
    spec = importlib.util.find_spec(module)
    locations = list(spec.submodule_search_locations or []) if spec is not None else []
    return str(locations[0]) if locations else None


@functools.cache
def tensorrt_problem() -> str | None:
    """Why TensorRT's ``libnvinfer`` cannot be loaded, or None when the loader finds it.

    onnxruntime's TensorRT provider loads it by name, so it must be on the loader's path;
    the ``tensorrt`` wheels put it in ``tensorrt_libs``, which is not there by itself.
    """
    for name in _tensorrt_candidates():
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        return None
    folder = _wheel_folder('tensorrt_libs')
    if folder is not None and any(Path(folder).glob('*nvinfer*')):
        return (
            f'TensorRT is installed in {folder} but not on the library path: '
            f'export LD_LIBRARY_PATH={folder}:$LD_LIBRARY_PATH ({_DOCS})'
        )
    return f'TensorRT libraries (libnvinfer) not found: pip install tensorrt-cu12 ({_DOCS})'


def _join(problems: Sequence[str | None]) -> Availability:
    found = [p for p in problems if p]
    return Availability(ok=not found, reason='; '.join(found))


def cuda_availability() -> Availability:
    """The ``cuda`` backend: a GPU, torch with CUDA, and ORT's CUDA provider or onnx2torch."""
    driver = driver_problem()
    torch_missing = module_missing('torch')
    ort = ort_provider_problem('CUDAExecutionProvider')
    engine = None
    if ort is not None and module_missing('onnx2torch'):
        engine = (
            f'no inference engine: {ort}; or, for --engine torch, onnx2torch is not installed: '
            f'{GPU_EXTRA}'
        )
    problems = [driver]
    if torch_missing:
        problems.append(f'torch is not installed (GPU pre/post-processing needs it): {GPU_EXTRA}')
    problems.append(engine)
    if driver is None and not torch_missing:
        problems.append(torch_problem())
    return _join(problems)


def tensorrt_availability() -> Availability:
    """The ``tensorrt`` backend: a GPU, torch with CUDA, ORT's TensorRT provider, libnvinfer."""
    driver = driver_problem()
    problems = [driver, ort_provider_problem('TensorrtExecutionProvider')]
    problems.append(tensorrt_problem())
    if module_missing('torch'):
        problems.append(f'torch is not installed (GPU pre/post-processing needs it): {GPU_EXTRA}')
    elif driver is None:
        problems.append(torch_problem())
    return _join(problems)


def hsv_cuda_availability() -> Availability:
    """The ``hsv-cuda`` backend: a GPU and CuPy."""
    driver = driver_problem()
    if module_missing('cupy'):
        return _join([driver, f'cupy not installed: {GPU_EXTRA}'])
    return _join([driver, cupy_problem() if driver is None else None])


def check_session_providers(session: Any, wanted: str) -> list[str]:
    """The session's providers; ``BackendUnavailableError`` unless ``wanted`` is the first.

    onnxruntime drops a provider it cannot load (no GPU, missing CUDA / cuDNN / TensorRT
    libraries) with only a warning and runs on the next one, the CPU at the end: what the
    session reports is the only honest check.
    """
    providers = [str(p) for p in session.get_providers()]
    if not providers or providers[0] != wanted:
        shown = ', '.join(providers) or 'none'
        msg = (
            f'onnxruntime did not enable {wanted} (the session runs on: {shown}); '
            f'the GPU, the driver or the CUDA/cuDNN{"/TensorRT" if "Tensorrt" in wanted else ""} '
            f'libraries it needs are missing or unusable ({_DOCS}); refusing to run on the CPU'
        )
        raise BackendUnavailableError(msg)
    return providers
