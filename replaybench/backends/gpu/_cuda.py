"""NVIDIA driver facts through the CUDA driver API (ctypes), stage clocks and cache folders.

Nothing here imports torch, CuPy or onnxruntime: loading ``libcuda`` and asking it for the
device count is how the GPU backends tell, cheaply, whether a GPU is there at all.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import importlib.util
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from replaybench.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = [
    'DeviceFacts',
    'StageClock',
    'cache_dir',
    'device_facts',
    'driver_problem',
    'load_libcuda',
    'nvidia_driver_release',
]

#: CUresult codes worth naming in a message (cuda.h).
_CU_ERRORS = {
    3: 'CUDA_ERROR_NOT_INITIALIZED',
    34: 'CUDA_ERROR_STUB_LIBRARY (the libcuda found is a stub, not the driver)',
    35: 'CUDA_ERROR_INSUFFICIENT_DRIVER',
    100: 'CUDA_ERROR_NO_DEVICE',
    101: 'CUDA_ERROR_INVALID_DEVICE',
    304: 'CUDA_ERROR_OPERATING_SYSTEM',
    999: 'CUDA_ERROR_UNKNOWN',
}
_NO_DRIVER = 'no NVIDIA GPU/driver found (libcuda not loadable)'


def _library_names() -> list[str]:
    if sys.platform == 'win32':
        return ['nvcuda.dll']
    names = ['libcuda.so.1', 'libcuda.so']
    found = ctypes.util.find_library('cuda')
    if found and found not in names:
        names.append(found)
    return names


@functools.cache
def load_libcuda() -> ctypes.CDLL | None:
    """The CUDA driver library, or None where no NVIDIA driver is installed."""
    for name in _library_names():
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    return None


def _cu_error(code: int) -> str:
    return f'CUresult {code}' + (f' {_CU_ERRORS[code]}' if code in _CU_ERRORS else '')


@functools.cache
def _device_count() -> tuple[int, str]:
    """(number of visible devices, problem); the problem is '' when the driver answered."""
    lib = load_libcuda()
    if lib is None:
        return 0, _NO_DRIVER
    code = lib.cuInit(0)
    if code != 0:
        return 0, f'NVIDIA driver found but cuInit failed ({_cu_error(code)}): no usable GPU'
    count = ctypes.c_int(0)
    code = lib.cuDeviceGetCount(ctypes.byref(count))
    if code != 0:
        return 0, f'cuDeviceGetCount failed ({_cu_error(code)})'
    if count.value == 0:
        visible = os.environ.get('CUDA_VISIBLE_DEVICES')
        where = f' (CUDA_VISIBLE_DEVICES={visible!r})' if visible is not None else ''
        return 0, f'NVIDIA driver found but no GPU is visible{where}'
    return count.value, ''


def driver_problem(device: int | None = None) -> str | None:
    """Why no GPU can be used (one line), or None when the driver reports ``device`` (any: None)."""
    count, problem = _device_count()
    if problem:
        return problem
    if device is not None and not 0 <= device < count:
        return f'no GPU with index {device}: this machine has {count} (0..{count - 1})'
    return None


class DeviceFacts(NamedTuple):
    """What run.json records about the GPU a backend ran on."""

    device: int
    name: str
    total_memory_bytes: int
    driver: str
    cuda_driver_api: str


def nvidia_driver_release() -> str | None:
    """The driver release (``550.54.15``) via NVML (``nvidia-ml-py``), None when unavailable."""
    if importlib.util.find_spec('pynvml') is None:
        return None
    try:
        pynvml = importlib.import_module('pynvml')
        pynvml.nvmlInit()
        try:
            release = pynvml.nvmlSystemGetDriverVersion()
        finally:
            pynvml.nvmlShutdown()
    except Exception:  # NVML missing or refusing: the release is optional
        return None
    return release.decode() if isinstance(release, bytes) else str(release)


def device_facts(index: int) -> DeviceFacts:
    """Name, memory and driver of GPU ``index``; ``BackendUnavailableError`` without one."""
    problem = driver_problem(index)
    lib = load_libcuda()
    if problem is not None or lib is None:
        raise BackendUnavailableError(problem or _NO_DRIVER)
    dev = ctypes.c_int(0)
    name = ctypes.create_string_buffer(256)
    memory = ctypes.c_size_t(0)
    version = ctypes.c_int(0)
    checks = (
        lib.cuDeviceGet(ctypes.byref(dev), index),
        lib.cuDeviceGetName(name, len(name), dev),
        lib.cuDeviceTotalMem_v2(ctypes.byref(memory), dev),
        lib.cuDriverGetVersion(ctypes.byref(version)),
    )
    failed = [code for code in checks if code != 0]
    if failed:
        msg = f'GPU {index}: the CUDA driver refused a device query ({_cu_error(failed[0])})'
        raise BackendUnavailableError(msg)
    api = f'{version.value // 1000}.{version.value % 1000 // 10}'
    return DeviceFacts(
        device=index,
        name=name.value.decode(errors='replace'),
        total_memory_bytes=int(memory.value),
        driver=nvidia_driver_release() or f'CUDA driver API {api}',
        cuda_driver_api=api,
    )


def cache_dir(*parts: str) -> Path:
    """``$XDG_CACHE_HOME/replaybench/...`` (default ``~/.cache``; ``%LOCALAPPDATA%`` on Windows)."""
    if sys.platform == 'win32':
        base = Path(os.environ.get('LOCALAPPDATA') or Path.home() / 'AppData' / 'Local')
    else:
        xdg = os.environ.get('XDG_CACHE_HOME', '')
        base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / '.cache'
    return base.joinpath('replaybench', *parts)


class StageClock:
    """Stage durations of device work: each lap synchronises the device, then reads the clock.

    ``synchronize`` blocks until all work queued on the backend's stream is done, so a lap
    measures when the device finished the stage, not when the host finished queueing it.
    """

    def __init__(self, synchronize: Callable[[], object]) -> None:
        self._synchronize = synchronize
        self._last = 0

    def start(self) -> None:
        self._synchronize()
        self._last = time.perf_counter_ns()

    def lap(self) -> int:
        """Nanoseconds since ``start`` or the previous lap, device work included."""
        self._synchronize()
        now = time.perf_counter_ns()
        elapsed = now - self._last
        self._last = now
        return elapsed
