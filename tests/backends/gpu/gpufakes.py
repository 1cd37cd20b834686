"""Stand-ins at the hardware / driver boundary for the GPU backend tests on a machine without a
GPU (imported as ``backends.gpu.gpufakes``).

* ``FakeLibcuda``: the CUDA driver API as ``ctypes`` calls it (``cuInit``, ``cuDeviceGet*``),
  answering for made-up GPUs; ``install_libcuda`` makes ``_cuda.load_libcuda`` return it.
* ``fake_nvml``: a ``pynvml`` module over the same GPUs, numbered in PCI order as NVML does.
* ``fake_loader``: the shared-library loader of ``_libs`` (``ctypes.CDLL``) answering from a
  table of library names.
* ``fake_gpu_build``: onnxruntime as onnxruntime-gpu behaves: the build lists the GPU providers,
  a session reports the providers and node placement a GPU session would, while the real CPU
  provider computes.
* ``torch_on_the_cpu``: torch's CUDA calls (streams, device contexts, the caching allocator)
  answered on the CPU; the tensors are real torch CPU tensors.
* ``fake_cupy``: NumPy in CuPy's place (``set`` / ``get``, streams, events, memory pools).

Everything the backends compute still runs for real.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import types
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import onnxruntime
import pytest

from replaybench.backends.gpu import _cuda, _libs
from replaybench.backends.gpu import availability as availability_module
from replaybench.backends.gpu import tensorrt as tensorrt_module
from replaybench.backends.gpu.cuda import CudaBackend

if TYPE_CHECKING:
    from collections.abc import Callable

GPU_PROVIDERS = ['TensorrtExecutionProvider', 'CUDAExecutionProvider', 'CPUExecutionProvider']


@dataclass(frozen=True)
class FakeGpu:
    """One physical GPU as the driver and NVML describe it."""

    name: str
    uuid: bytes  # 16 bytes
    pci_bus_id: str  # as CUDA writes it: 0000:65:00.0
    compute_capability: tuple[int, int] = (8, 6)
    memory: int = 24 << 30
    used: int = 1 << 30

    @property
    def uuid_text(self) -> str:
        h = self.uuid.hex()
        return f'GPU-{h[0:8]}-{h[8:12]}-{h[12:16]}-{h[16:20]}-{h[20:32]}'


GPU_A = FakeGpu('Fake GPU A', bytes(range(16)), '0000:17:00.0', (8, 6), 24 << 30, 1 << 30)
GPU_B = FakeGpu('Fake GPU B', bytes(range(16, 32)), '0000:65:00.0', (9, 0), 80 << 30, 5 << 30)


def _out(arg: Any) -> Any:
    """The ctypes object behind ``ctypes.byref(x)``."""
    return arg._obj if hasattr(arg, '_obj') else arg


@dataclass
class FakeLibcuda:
    """``libcuda`` for ``gpus``; ``visible`` lists the physical GPU behind each CUDA ordinal
    (what ``CUDA_VISIBLE_DEVICES`` does), ``driver`` is ``cuDriverGetVersion``'s answer."""

    gpus: list[FakeGpu]
    visible: list[int] | None = None
    driver: int = 13000
    init_result: int = 0
    calls: list[str] = field(default_factory=list)

    def _gpu(self, dev: Any) -> FakeGpu:
        return self.gpus[int(dev.value if hasattr(dev, 'value') else dev)]

    def _order(self) -> list[int]:
        return list(range(len(self.gpus))) if self.visible is None else self.visible

    def cuInit(self, flags: int) -> int:
        self.calls.append('cuInit')
        return self.init_result

    def cuDeviceGetCount(self, count: Any) -> int:
        _out(count).value = len(self._order())
        return 0

    def cuDeviceGet(self, dev: Any, ordinal: int) -> int:
        order = self._order()
        if not 0 <= ordinal < len(order):
            return 101
        _out(dev).value = order[ordinal]
        return 0

    def cuDeviceGetName(self, buffer: Any, length: int, dev: Any) -> int:
        buffer.value = self._gpu(dev).name.encode()
        return 0

    def cuDeviceTotalMem_v2(self, memory: Any, dev: Any) -> int:
        _out(memory).value = self._gpu(dev).memory
        return 0

    def cuDriverGetVersion(self, version: Any) -> int:
        _out(version).value = self.driver
        return 0

    def cuDeviceGetPCIBusId(self, buffer: Any, length: int, dev: Any) -> int:
        buffer.value = self._gpu(dev).pci_bus_id.upper().encode()
        return 0

    def cuDeviceGetUuid(self, buffer: Any, dev: Any) -> int:
        ctypes.memmove(buffer, self._gpu(dev).uuid, 16)
        return 0

    def cuDeviceGetAttribute(self, value: Any, attribute: int, dev: Any) -> int:
        major, minor = self._gpu(dev).compute_capability
        _out(value).value = {75: major, 76: minor}[attribute]
        return 0


def install_libcuda(
    monkeypatch: pytest.MonkeyPatch, fake: FakeLibcuda | None, release: str | None = None
) -> None:
    """Make the driver queries of ``_cuda`` go to ``fake`` (None: no driver at all), with NVML
    reporting driver ``release``. The caller clears ``_cuda._device_count`` when done."""
    _cuda._device_count.cache_clear()
    monkeypatch.setattr(_cuda, 'load_libcuda', lambda: fake)
    monkeypatch.setattr(_cuda, 'nvidia_driver_release', lambda: release)


def fake_nvml(
    gpus: list[FakeGpu],
    release: str = '580.65.06',
    used: Callable[[FakeGpu], int] | None = None,
) -> types.ModuleType:
    """A ``pynvml`` module over ``gpus``, numbered as listed (NVML's PCI order); ``used`` gives
    a GPU's memory in use at each reading (default: its fixed ``used``)."""
    module = types.ModuleType('pynvml')
    state: dict[str, Any] = {'shutdown': 0, 'read': []}

    def handle(index: int) -> FakeGpu:
        return gpus[index]

    def memory(gpu: FakeGpu) -> Any:
        state['read'].append(gpu.name)
        return types.SimpleNamespace(used=gpu.used if used is None else used(gpu), total=gpu.memory)

    def pci(gpu: FakeGpu) -> Any:  # NVML writes 8 domain digits
        return types.SimpleNamespace(busId=('0000' + gpu.pci_bus_id).upper().encode())

    attrs = {
        'nvmlInit': lambda: None,
        'nvmlShutdown': lambda: state.__setitem__('shutdown', state['shutdown'] + 1),
        'nvmlDeviceGetCount': lambda: len(gpus),
        'nvmlDeviceGetHandleByIndex': handle,
        'nvmlDeviceGetName': lambda g: g.name.encode(),
        'nvmlDeviceGetUUID': lambda g: g.uuid_text,
        'nvmlDeviceGetPciInfo': pci,
        'nvmlDeviceGetUtilizationRates': lambda g: types.SimpleNamespace(gpu=50, memory=10),
        'nvmlDeviceGetMemoryInfo': memory,
        'nvmlDeviceGetPowerUsage': lambda g: 100_000,
        'nvmlSystemGetDriverVersion': lambda: release,
        'state': state,
    }
    for name, value in attrs.items():
        setattr(module, name, value)
    return module


class FakeLibrary:
    """A loaded shared library answering the version calls replaybench makes."""

    def __init__(self, name: str, version: int | None = None) -> None:
        self.name = name
        self.version = version

    def _fn(self, value: int | None) -> Any:
        def call(*args: Any) -> int:
            if args:  # cudaRuntimeGetVersion(int*)
                _out(args[0]).value = value or 0
                return 0
            return value or 0

        call.restype = None  # type: ignore[attr-defined]
        return call

    def __getattr__(self, attr: str) -> Any:
        if attr in ('getInferLibVersion', 'cudnnGetVersion', 'cudaRuntimeGetVersion'):
            return self._fn(self.version)
        raise AttributeError(attr)


def fake_loader(monkeypatch: pytest.MonkeyPatch, libraries: dict[str, int | None]) -> list[str]:
    """``_libs`` loads only ``libraries`` (name or path -> version it reports); the names
    asked for are returned, in order. Clears the cached TensorRT answer."""
    asked: list[str] = []

    def dlopen(name: str) -> FakeLibrary:
        asked.append(name)
        if name not in libraries:
            msg = f'{name}: cannot open shared object file: No such file or directory'
            raise OSError(msg)
        return FakeLibrary(name, libraries[name])

    monkeypatch.setattr(_libs, '_dlopen', dlopen)
    monkeypatch.setattr(_libs, '_wheel_folders', list)
    # a cache of its own for the answer from these libraries, gone with the test
    fresh = functools.cache(availability_module.tensorrt_problem.__wrapped__)
    monkeypatch.setattr(availability_module, 'tensorrt_problem', fresh)
    monkeypatch.setattr(tensorrt_module, 'tensorrt_problem', fresh)
    return asked


@dataclass
class FakeSubgraph:
    """One entry of ``get_provider_graph_assignment_info``."""

    ep_name: str
    nodes: list[Any]

    def get_nodes(self) -> list[Any]:
        return self.nodes


@dataclass
class GpuBuild:
    """What ``fake_gpu_build`` saw: the providers and session options each session was given."""

    providers: list[Any] = field(default_factory=list)
    options: list[Any] = field(default_factory=list)
    runs: int = 0


def fake_gpu_build(
    monkeypatch: pytest.MonkeyPatch,
    reported: list[str],
    placement: dict[str, str] | None = None,
    after_run: list[str] | None = None,
) -> GpuBuild:
    """onnxruntime as onnxruntime-gpu: the build lists the GPU providers; each session reports
    ``reported`` as its providers (``after_run`` once it has run) and its nodes placed as
    ``placement`` maps the CPU provider's real placement (default: the first reported
    provider takes every node). The real CPU provider computes the outputs."""
    real = onnxruntime.InferenceSession
    seen = GpuBuild()
    rename = placement if placement is not None else {'CPUExecutionProvider': reported[0]}

    class Session(real):  # type: ignore[misc, valid-type]
        def __init__(self, path: str, options: Any = None, providers: Any = None) -> None:
            seen.providers.append(providers)
            seen.options.append(options)
            cpu = onnxruntime.SessionOptions()
            cpu.intra_op_num_threads = 1
            cpu.add_session_config_entry('session.record_ep_graph_assignment_info', '1')
            super().__init__(path, cpu, providers=['CPUExecutionProvider'])
            self._ran = False

        def get_providers(self) -> list[str]:
            return list(after_run if self._ran and after_run is not None else reported)

        def run_with_iobinding(self, binding: Any, run_options: Any = None) -> None:
            seen.runs += 1
            self._ran = True
            super().run_with_iobinding(binding, run_options)

        def get_provider_graph_assignment_info(self) -> list[FakeSubgraph]:
            found = super().get_provider_graph_assignment_info()
            return [FakeSubgraph(rename.get(g.ep_name, g.ep_name), g.get_nodes()) for g in found]

    monkeypatch.setattr(onnxruntime, 'get_available_providers', lambda: list(GPU_PROVIDERS))
    monkeypatch.setattr(onnxruntime, 'InferenceSession', Session)
    return seen


class FakeStream:
    """A CUDA stream stand-in: a context manager with ``synchronize`` and a handle."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.synchronized = 0
        self.cuda_stream = 0

    def synchronize(self) -> None:
        self.synchronized += 1

    def __enter__(self) -> FakeStream:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


class FakeTorchCuda:
    """``torch.cuda`` stand-in: streams and device contexts that do nothing, and the caching
    allocator's ``empty_cache`` counted."""

    Stream = FakeStream
    emptied = 0

    @staticmethod
    def stream(stream: Any) -> Any:
        return contextlib.nullcontext()

    @staticmethod
    def device(device: Any) -> Any:
        return contextlib.nullcontext()

    @classmethod
    def empty_cache(cls) -> None:
        cls.emptied += 1


def torch_on_the_cpu(monkeypatch: pytest.MonkeyPatch, torch: Any, cuda: str = '13.0') -> Any:
    """CudaBackend gets CPU torch whose ``torch.cuda`` is ``FakeTorchCuda``; returns it."""
    stand_in = types.SimpleNamespace(**{k: getattr(torch, k) for k in dir(torch) if k[0] != '_'})
    fake_cuda = type('FakeCuda', (FakeTorchCuda,), {'emptied': 0})
    stand_in.cuda = fake_cuda
    stand_in.version = types.SimpleNamespace(cuda=cuda)
    stand_in.__version__ = torch.__version__
    monkeypatch.setattr(CudaBackend, '_torch_device', lambda self: (stand_in, torch.device('cpu')))
    return fake_cuda


class DeviceArray(np.ndarray):
    """A NumPy array with CuPy's ``set`` / ``get``."""

    def set(self, array: np.ndarray, stream: Any = None) -> None:
        self[...] = array

    def get(self, stream: Any = None) -> np.ndarray:
        return np.asarray(self).copy()


@dataclass
class FakeEvent:
    """A CUDA event: ``record`` stamps the fake device clock."""

    clock: list[float]
    stamp: float | None = None

    def record(self, stream: Any = None) -> None:
        self.clock[0] += 0.25  # each recorded stage takes 0.25 ms of device time
        self.stamp = self.clock[0]


@dataclass
class CupyState:
    """CuPy's current device and current stream (what ``with Device`` / ``with Stream`` set),
    and the host -> device copies ``asarray`` made: (device, stream) each."""

    devices: list[int] = field(default_factory=lambda: [0])
    streams: list[Any] = field(default_factory=lambda: [None])
    copies: list[tuple[int, Any]] = field(default_factory=list)

    @property
    def device(self) -> int:
        return self.devices[-1]

    @property
    def stream(self) -> Any:
        return self.streams[-1]


@dataclass
class FakePool:
    """A memory pool; ``freed_on`` lists the current device at each ``free_all_blocks``."""

    state: CupyState | None = None
    freed: int = 0
    freed_on: list[int] = field(default_factory=list)

    def free_all_blocks(self) -> None:
        self.freed += 1
        if self.state is not None:
            self.freed_on.append(self.state.device)


def fake_cupy() -> tuple[Any, Any, Any]:
    """(cupy, cupyx, cupyx.scipy.ndimage) with NumPy and SciPy doing the work.

    ``cupy.state`` (``CupyState``) follows the current device and stream as CuPy's context
    managers set them; the default memory pool frees the current device's blocks as CuPy's does.
    """
    ndimage = pytest.importorskip('scipy.ndimage', reason='scipy is not installed')
    numpy_like = types.SimpleNamespace(
        **{k: getattr(np, k) for k in dir(np) if not k.startswith('_')}
    )
    state = CupyState()

    @contextlib.contextmanager
    def device(index: int) -> Any:
        state.devices.append(index)
        try:
            yield
        finally:
            state.devices.pop()

    class Device:
        def __init__(self, index: int) -> None:
            self.index = index
            self._entered: list[Any] = []

        def __enter__(self) -> Device:
            context = device(self.index)
            context.__enter__()
            self._entered.append(context)
            return self

        def __exit__(self, *exc: object) -> None:
            self._entered.pop().__exit__(None, None, None)

    class Stream(FakeStream):
        def __enter__(self) -> Stream:
            state.streams.append(self)
            return self

        def __exit__(self, *exc: object) -> None:
            state.streams.pop()

    def asarray(array: Any, dtype: Any = None) -> Any:
        state.copies.append((state.device, state.stream))
        return np.asarray(array, dtype)

    numpy_like.state = state
    numpy_like.asarray = asarray
    numpy_like.empty = lambda shape, dtype=None: np.empty(shape, dtype).view(DeviceArray)
    numpy_like.stack = lambda arrays, axis=0: np.stack(arrays, axis).view(DeviceArray)
    numpy_like.zeros = lambda shape, dtype=float: np.zeros(shape, dtype).view(DeviceArray)
    numpy_like.__version__ = 'numpy stand-in'
    clock = [0.0]
    numpy_like.device_clock = clock
    numpy_like.pools = (FakePool(state), FakePool())
    numpy_like.get_default_memory_pool = lambda: numpy_like.pools[0]
    numpy_like.get_default_pinned_memory_pool = lambda: numpy_like.pools[1]
    numpy_like.cuda = types.SimpleNamespace(
        Device=Device,
        Stream=Stream,
        Event=lambda: FakeEvent(clock),
        get_elapsed_time=lambda a, b: b.stamp - a.stamp,
        runtime=types.SimpleNamespace(runtimeGetVersion=lambda: 13000),
    )
    cupyx = types.SimpleNamespace(empty_pinned=lambda shape, dtype=None: np.empty(shape, dtype))
    return numpy_like, cupyx, ndimage
