"""The machine a run is measured on, as run.json's ``environment`` records it: CPU, memory,
operating system, Python, the library versions that shape the measurements, the load and the
GPUs ``nvidia-smi`` lists. The load average is taken before the replay (``load_snapshot``), so
that it describes the machine, not the run; the rest is described after the replay
(``describe_machine(load)``), so that nothing it costs (importing OpenCV for its version, running
``nvidia-smi``) delays the first frame."""

from __future__ import annotations

import os
import platform
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench._version import __version__

if TYPE_CHECKING:
    from collections.abc import Iterable

    from replaybench.results.model import Environment

__all__ = ['LoadSnapshot', 'describe_machine', 'environment', 'load_snapshot']

_DISTRIBUTIONS: dict[str, tuple[str, ...]] = {
    'numpy': ('numpy',),
    'onnxruntime': (
        'onnxruntime',
        'onnxruntime-gpu',
        'onnxruntime-openvino',
        'onnxruntime-directml',
    ),
    'mcap': ('mcap',),
    'rosbags': ('rosbags',),
}


def _version(names: Iterable[str]) -> str | None:
    from importlib import metadata  # imported on use: it costs more than the rest of this module

    for name in names:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return None


def _read_text(path: str) -> str | None:
    try:
        return Path(path).read_text(encoding='utf-8', errors='replace')
    except OSError:
        return None


def _cpu_model() -> str:
    text = _read_text('/proc/cpuinfo')
    if text:
        for key in ('model name', 'Model', 'Hardware', 'cpu model'):
            for line in text.splitlines():
                name, sep, value = line.partition(':')
                if sep and name.strip() == key and value.strip():
                    return value.strip()
    return platform.processor() or platform.machine()


def _hostname() -> str | None:
    return platform.node() or None


def _memory_total_bytes() -> int | None:
    text = _read_text('/proc/meminfo')
    if text:
        for line in text.splitlines():
            if line.startswith('MemTotal:'):
                parts = line.split()
                if len(parts) >= 2 and parts[1].isdigit():
                    return int(parts[1]) * 1024
    return None


def _usable_cores() -> int | None:
    if hasattr(os, 'sched_getaffinity'):
        return len(os.sched_getaffinity(0))
    return os.cpu_count()


def _opencv() -> dict[str, Any]:
    try:
        import cv2
    except ImportError:
        return {'version': None, 'threads': None}
    return {'version': str(cv2.__version__), 'threads': int(cv2.getNumThreads())}


def _gpus() -> list[dict[str, str]]:
    exe = shutil.which('nvidia-smi')
    if exe is None:
        return []
    try:
        proc = subprocess.run(
            [exe, '--query-gpu=name,driver_version,memory.total', '--format=csv,noheader'],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return []
    if proc.returncode != 0:
        return []
    gpus = []
    for line in proc.stdout.splitlines():
        parts = [part.strip() for part in line.split(',')]
        if len(parts) == 3 and parts[0]:
            gpus.append({'name': parts[0], 'driver_version': parts[1], 'memory_total': parts[2]})
    return gpus


@dataclass(frozen=True, slots=True)
class LoadSnapshot:
    """The load average at one moment (1, 5 and 15 minutes); None where the system has none."""

    values: tuple[float, ...] | None


def load_snapshot() -> LoadSnapshot:
    """The load average now (cheap: taken before the replay, described after it)."""
    try:
        return LoadSnapshot(tuple(round(v, 2) for v in os.getloadavg()))
    except OSError:
        return LoadSnapshot(None)


def environment() -> dict[str, Any]:
    """Describe this machine and the library versions that shape the measurements."""
    governor = _read_text('/sys/devices/system/cpu/cpu0/cpufreq/scaling_governor')
    snapshot = load_snapshot().values
    load = list(snapshot) if snapshot is not None else None
    return {
        'hostname': _hostname(),
        'cpu': {
            'model': _cpu_model(),
            'logical_cores': os.cpu_count(),
            'usable_cores': _usable_cores(),
            'machine': platform.machine(),
            'governor': governor.strip() if governor else None,
        },
        'memory_total_bytes': _memory_total_bytes(),
        'os': {
            'system': platform.system(),
            'release': platform.release(),
            'version': platform.version(),
            'platform': platform.platform(),
        },
        'python': {
            'version': platform.python_version(),
            'implementation': platform.python_implementation(),
            'executable': sys.executable,
        },
        'packages': {
            'replaybench': __version__,
            **{key: _version(names) for key, names in _DISTRIBUTIONS.items()},
            'opencv': _opencv(),
        },
        'load_average': load,
        'gpus': _gpus(),
    }


def describe_machine(load: LoadSnapshot | None = None) -> Environment:
    """``environment()`` as the typed ``Environment`` run.json holds; with ``load``, its load
    average is that snapshot's (taken earlier) instead of the load now."""
    from replaybench.results.model import (
        CpuInfo,
        Environment,
        GpuInfo,
        OpenCvInfo,
        OsInfo,
        Packages,
        PythonInfo,
    )

    found = environment()
    if load is not None:
        found['load_average'] = list(load.values) if load.values is not None else None
    cpu, os_info, python, packages = (
        found['cpu'],
        found['os'],
        found['python'],
        found['packages'],
    )
    averages = found['load_average']
    return Environment(
        hostname=found['hostname'],
        cpu=CpuInfo(**cpu),
        memory_total_bytes=found['memory_total_bytes'],
        os=OsInfo(**os_info),
        python=PythonInfo(**python),
        packages=Packages(
            **{key: value for key, value in packages.items() if key != 'opencv'},
            opencv=OpenCvInfo(**packages['opencv']),
        ),
        load_average=tuple(float(v) for v in averages) if averages is not None else None,
        gpus=tuple(GpuInfo(**gpu) for gpu in found['gpus']),
    )
