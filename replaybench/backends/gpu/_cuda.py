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
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = [
    'MIN_DRIVER_RELEASE',
    'STAGE_EVENTS',
    'DeviceFacts',
    'DeviceIdentity',
    'EventTimer',
    'StageClock',
    'cache_dir',
    'device_count',
    'device_facts',
    'device_identity',
    'driver_api_version',
    'driver_problem',
    'load_libcuda',
    'normalise_pci_bus_id',
    'nvidia_driver_release',
]

#: The oldest NVIDIA driver branch that runs CUDA 13 (the CUDA major of the ``gpu`` extra).
MIN_DRIVER_RELEASE = 580
#: Timing events per frame: a start and an end event for each of the 5 stages (``StageClock``).
STAGE_EVENTS = 10
#: ``CUdevice_attribute`` values (cuda.h).
_CC_MAJOR = 75
_CC_MINOR = 76

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


def device_count() -> int:
    """The number of GPUs this process sees (0 without a driver or a visible GPU)."""
    return _device_count()[0]


def driver_problem(device: int | None = None) -> str | None:
    """Why no GPU can be used (one line), or None when the driver reports ``device`` (any: None)."""
    count, problem = _device_count()
    if problem:
        return problem
    if device is not None and not 0 <= device < count:
        return f'no GPU with index {device}: this machine has {count} (0..{count - 1})'
    return None


class DeviceFacts(NamedTuple):
    """What run.json records about the GPU a backend ran on.

    ``compute_capability`` is ``major.minor`` (``8.6``); ``pci_bus_id`` and ``uuid`` identify
    the device whatever ``CUDA_VISIBLE_DEVICES`` does to the index (NVML's ``GPU-...`` form).
    """

    device: int
    name: str
    total_memory_bytes: int
    driver: str
    cuda_driver_api: str
    compute_capability: str = ''
    pci_bus_id: str = ''
    uuid: str = ''


class DeviceIdentity(NamedTuple):
    """The PCI bus id (``0000:65:00.0``) and UUID (``GPU-...``) of one CUDA device."""

    pci_bus_id: str
    uuid: str


def normalise_pci_bus_id(text: str) -> str:
    """``domain:bus:device.function`` as ``0000:65:00.0``, however many domain digits it has.

    CUDA writes 4 domain digits, NVML 8 (``00000000:65:00.0``); both name the same device.
    Text that is not a PCI address comes back lower-cased and stripped.
    """
    cleaned = text.strip().lower()
    try:
        domain, bus, rest = cleaned.split(':')
        device, function = rest.split('.')
        parts = (int(domain, 16), int(bus, 16), int(device, 16), int(function, 16))
    except ValueError:
        return cleaned
    return '{:04x}:{:02x}:{:02x}.{:x}'.format(*parts)


def _uuid_text(raw: bytes) -> str:
    """16 UUID bytes as NVML writes them: ``GPU-xxxxxxxx-xxxx-xxxx-xxxx-xxxxxxxxxxxx``."""
    h = raw.hex()
    return f'GPU-{h[0:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:32]}'


def _identity(lib: ctypes.CDLL, dev: ctypes.c_int) -> tuple[DeviceIdentity, str, int]:
    """(identity, compute capability, first failing CUresult or 0) of a ``CUdevice``."""
    bus = ctypes.create_string_buffer(64)
    uuid = ctypes.create_string_buffer(16)
    major = ctypes.c_int(0)
    minor = ctypes.c_int(0)
    codes = (
        lib.cuDeviceGetPCIBusId(bus, len(bus), dev),
        lib.cuDeviceGetUuid(uuid, dev),
        lib.cuDeviceGetAttribute(ctypes.byref(major), _CC_MAJOR, dev),
        lib.cuDeviceGetAttribute(ctypes.byref(minor), _CC_MINOR, dev),
    )
    failed = next((code for code in codes if code != 0), 0)
    identity = DeviceIdentity(
        normalise_pci_bus_id(bus.value.decode(errors='replace')), _uuid_text(uuid.raw)
    )
    return identity, f'{major.value}.{minor.value}', failed


def device_identity(index: int) -> DeviceIdentity | None:
    """PCI bus id and UUID of CUDA device ``index`` (as this process numbers devices, after
    ``CUDA_VISIBLE_DEVICES`` and ``CUDA_DEVICE_ORDER``); None without a driver or device."""
    lib = load_libcuda()
    if driver_problem(index) is not None or lib is None:
        return None
    dev = ctypes.c_int(0)
    if lib.cuDeviceGet(ctypes.byref(dev), index) != 0:
        return None
    identity, _, failed = _identity(lib, dev)
    return None if failed else identity


def driver_api_version() -> int | None:
    """``cuDriverGetVersion``: the newest CUDA the driver supports (13000 = 13.0), or None."""
    lib = load_libcuda()
    if lib is None:
        return None
    version = ctypes.c_int(0)
    if lib.cuDriverGetVersion(ctypes.byref(version)) != 0:
        return None
    return int(version.value)


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
    except Exception:  # noqa: BLE001  NVML missing or refusing: the release is optional
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
    checks = [
        lib.cuDeviceGet(ctypes.byref(dev), index),
        lib.cuDeviceGetName(name, len(name), dev),
        lib.cuDeviceTotalMem_v2(ctypes.byref(memory), dev),
        lib.cuDriverGetVersion(ctypes.byref(version)),
    ]
    identity, capability, failed_identity = _identity(lib, dev)
    checks.append(failed_identity)
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
        compute_capability=capability,
        pci_bus_id=identity.pci_bus_id,
        uuid=identity.uuid,
    )


def cache_dir(*parts: str) -> Path:
    """``$XDG_CACHE_HOME/replaybench/...`` (default ``~/.cache``; ``%LOCALAPPDATA%`` on Windows)."""
    if sys.platform == 'win32':
        base = Path(os.environ.get('LOCALAPPDATA') or Path.home() / 'AppData' / 'Local')
    else:
        xdg = os.environ.get('XDG_CACHE_HOME', '')
        base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / '.cache'
    return base.joinpath('replaybench', *parts)


class EventTimer:
    """Timing events on one device stream, reused frame after frame (``slots`` of them).

    ``record(event)`` queues an event on the backend's stream; ``elapsed_ms(a, b)`` is the
    device time between two completed events (``torch.cuda.Event.elapsed_time``,
    ``cupy.cuda.get_elapsed_time``). Built by the backends from their own library's events.
    """

    def __init__(
        self,
        events: list[Any],
        record: Callable[[Any], object],
        elapsed_ms: Callable[[Any, Any], float],
    ) -> None:
        self.events = events
        self._record = record
        self._elapsed_ms = elapsed_ms

    def record(self, slot: int) -> None:
        self._record(self.events[slot])

    def elapsed_ns(self, start: int, end: int) -> int:
        return round(float(self._elapsed_ms(self.events[start], self.events[end])) * 1e6)


class StageClock:
    """Stage durations of device work, on the host's clock and on the device's.

    Per stage: ``begin()`` just before the stage's first GPU call, ``lap()`` after its last.

    Host: ``lap()`` synchronises the device, then reads ``perf_counter_ns``; a host lap runs
    from the previous lap (or ``start``) to that moment, so the host laps add up to the whole
    frame: host work before the first GPU call (a copy into pinned memory), launches, waits
    and synchronisation included.
    Device: with an ``EventTimer``, ``begin()`` records a start event on the backend's stream
    and ``lap()`` an end event just before it synchronises; ``device_laps()`` (after the last
    lap, when every event has completed) gives, per stage, the time the stream took from the
    start event to the end event: the stage's kernels and copies, the gaps between them while
    the host prepared the next launch, and any wait inside the stage for the host (a stage that
    synchronises part-way spends that time idle on the stream), but not the host work before
    ``begin()`` nor the synchronisation after ``lap()``.
    """

    def __init__(
        self,
        synchronize: Callable[[], object],
        events: EventTimer | None = None,
        stages: int = 5,
    ) -> None:
        self._synchronize = synchronize
        self._events = events
        if events is not None and len(events.events) < 2 * stages:
            have = len(events.events)
            msg = f'a StageClock of {stages} stages needs {2 * stages} events, not {have}'
            raise ValueError(msg)
        self._last = 0
        self._stage = 0
        self._begun = False

    def start(self) -> None:
        """Synchronise the device and start the host clock of the first stage."""
        self._stage = 0
        self._begun = False
        self._synchronize()
        self._last = time.perf_counter_ns()

    def begin(self) -> None:
        """Just before the stage's first GPU call: its start event on the stream."""
        if self._begun:
            msg = f'stage {self._stage} has begun already'
            raise RuntimeError(msg)
        self._begun = True
        if self._events is not None:
            self._events.record(2 * self._stage)

    def lap(self) -> int:
        """After the stage's last GPU call: its end event, then nanoseconds on the host since
        ``start`` or the previous lap, device work and synchronisation included."""
        if not self._begun:
            msg = f'stage {self._stage} ended without begin()'
            raise RuntimeError(msg)
        if self._events is not None:
            self._events.record(2 * self._stage + 1)
        self._synchronize()
        now = time.perf_counter_ns()
        elapsed = now - self._last
        self._last = now
        self._stage += 1
        self._begun = False
        return elapsed

    def device_laps(self) -> list[int | None]:
        """Device nanoseconds of each stage so far, start event to end event (None each
        without events)."""
        events = self._events
        if events is None:
            return [None] * self._stage
        return [events.elapsed_ns(2 * i, 2 * i + 1) for i in range(self._stage)]
