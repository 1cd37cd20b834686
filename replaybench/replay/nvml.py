"""One NVML device for the resource sampler (``replaybench.replay.resources``): the GPU's
utilisation, memory in use, power and clock-event reasons, each None where NVML cannot say.

The device is matched to the CUDA device of the run by UUID (else PCI bus id), since NVML
numbers devices in PCI order and ignores ``CUDA_VISIBLE_DEVICES``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from replaybench.backends.gpu import _cuda

if TYPE_CHECKING:
    from replaybench.backends.gpu._cuda import DeviceIdentity

__all__ = ['NvmlDevice', 'quiet']

_MIB = float(1 << 20)


class NvmlDevice:
    """One NVML device; every query returns None when it fails.

    The device is the one CUDA calls ``index`` in this process: NVML numbers devices by PCI
    order and ignores ``CUDA_VISIBLE_DEVICES`` / ``CUDA_DEVICE_ORDER``, so the CUDA device's
    UUID (else its PCI bus id), read from the CUDA driver, picks the NVML device (``match``).
    Only where no CUDA driver library loads at all is ``index`` taken as NVML's own
    (``match`` = ``index``); with no index given, NVML's device 0.
    """

    def __init__(
        self, module: Any, handle: Any, index: int, name: str, match: str, identity: Any
    ) -> None:
        self.module = module
        self.handle = handle
        self.index = index
        self.name = name
        self.match = match
        self.uuid = identity.uuid if identity is not None else None
        self.pci_bus_id = identity.pci_bus_id if identity is not None else None
        self.power_ok = True
        self.reasons_ok = True

    @classmethod
    def open(cls, index: int | None) -> NvmlDevice | None:
        try:
            module = importlib.import_module('pynvml')
        except ImportError:
            return None
        try:
            module.nvmlInit()
        except Exception:  # noqa: BLE001  NVML fails in its own error types: no GPU figures then
            return None
        try:
            wanted = 0 if index is None else index
            count = int(module.nvmlDeviceGetCount())
            identity = None
            handle, match = None, ''
            if index is not None and _cuda.load_libcuda() is not None:
                identity = _cuda.device_identity(index)
                found = None if identity is None else _by_identity(module, count, identity)
                if found is not None:
                    handle, match = found
            elif 0 <= wanted < count:
                handle, match = module.nvmlDeviceGetHandleByIndex(wanted), 'index'
            if handle is None:
                module.nvmlShutdown()
                return None
            name = module.nvmlDeviceGetName(handle)
        except Exception:  # noqa: BLE001  NVML fails in its own error types: no GPU figures then
            quiet(module.nvmlShutdown)
            return None
        if isinstance(name, bytes):
            name = name.decode('utf-8', 'replace')
        return cls(module, handle, wanted, str(name), match, identity)

    def read(self) -> tuple[float | None, float | None, float | None]:
        nvml, handle = self.module, self.handle
        util = quiet(lambda: float(nvml.nvmlDeviceGetUtilizationRates(handle).gpu))
        mem = quiet(lambda: float(nvml.nvmlDeviceGetMemoryInfo(handle).used) / _MIB)
        power = None
        if self.power_ok:
            power = quiet(lambda: float(nvml.nvmlDeviceGetPowerUsage(handle)) / 1000.0)
            self.power_ok = power is not None
        return util, mem, power

    def reasons(self) -> int | None:
        """The clock event (throttle) reason bits now, None where NVML cannot say."""
        if not self.reasons_ok:
            return None
        nvml, handle = self.module, self.handle
        getter = getattr(nvml, 'nvmlDeviceGetCurrentClocksEventReasons', None) or getattr(
            nvml, 'nvmlDeviceGetCurrentClocksThrottleReasons', None
        )
        found = None if getter is None else quiet(lambda: int(getter(handle)))
        self.reasons_ok = found is not None
        return found

    def close(self) -> None:
        quiet(self.module.nvmlShutdown)


def _text(value: Any) -> str:
    return value.decode('utf-8', 'replace') if isinstance(value, bytes) else str(value)


def _by_identity(module: Any, count: int, identity: DeviceIdentity) -> tuple[Any, str] | None:
    """The NVML device with the CUDA device's UUID, else its PCI bus id; (handle, how)."""
    found = None
    for nvml_index in range(count):
        handle = module.nvmlDeviceGetHandleByIndex(nvml_index)
        uuid = quiet(lambda h=handle: _text(module.nvmlDeviceGetUUID(h)))
        if uuid is not None and uuid.lower() == identity.uuid.lower():
            return handle, 'uuid'
        bus = quiet(lambda h=handle: _text(module.nvmlDeviceGetPciInfo(h).busId))
        if (
            found is None
            and bus is not None
            and _cuda.normalise_pci_bus_id(bus) == identity.pci_bus_id
        ):
            found = (handle, 'pci_bus_id')
    return found


def quiet(call: Any) -> Any:
    """``call()``, or None where it raises (a reading NVML refuses is left out)."""
    try:
        return call()
    except Exception:  # noqa: BLE001  a reading NVML refuses is left out
        return None
