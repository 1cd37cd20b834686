"""Sample this process's CPU and memory use, and a GPU's, in a background thread.

CPU time comes from ``time.process_time_ns`` (``CLOCK_PROCESS_CPUTIME_ID``: every thread of
the process, nanosecond resolution; ``/proc/self/stat`` counts in 10 ms ticks, too coarse for
0.1 s intervals). ``cpu_percent`` is CPU time over wall time in percent of one core, so a
process keeping two cores busy shows 200. Memory is read from ``/proc/self/statm``: the private
(anonymous) memory the process allocated, ``RssAnon`` = resident - shared pages, comes first;
the resident pages of mapped files and shared memory (``RssFile`` + ``RssShmem``: the
memory-mapped input, the loaded libraries), which the kernel can drop and read back, are
reported apart as ``mapped``, and their sum as ``rss``. Where there is no ``/proc``,
``resource.getrusage`` gives the peak RSS so far instead, and no private figure. GPU numbers
come from NVML when ``pynvml`` (the ``nvidia-ml-py`` or ``pynvml`` distribution) imports and
reports a device; they describe the whole device (every process on it), not only this one. The NVML
device is matched to the CUDA device the backend uses by UUID / PCI bus id (see ``NvmlDevice``).
Without NVML the GPU fields are None.

GPU memory per backend: the runner starts one sampler at the start of each backend's pass, when
every backend of the run is open already (models, sessions, engines loaded) and the backends
before it are closed. ``gpu_mem_mb_peak`` is the highest device memory used during the pass, so
it also counts the other open backends and every other process; ``gpu_mem_mb_start`` is the
device memory used at the first sample (the start of the pass) and ``gpu_mem_mb_pass_peak`` the
peak above it: what the backend's frames added on top of what was resident when its pass began
(buffers, allocator growth, workspaces), not the memory its ``open()`` took before the pass
(``GPU_MEM_BASIS``, recorded in the summary as ``gpu_mem_basis``).

Throttling: each sample also reads the current frequency of the CPUs this process may run on
(``/sys/devices/system/cpu/cpu*/cpufreq/scaling_cur_freq``, the highest of them, in MHz) and,
with NVML, the GPU's clock event (throttle) reasons. The kernel's thermal throttle counters
(``thermal_throttle/core_throttle_count`` and ``package_throttle_count``) are read at the start
and at the stop. Without cpufreq (many virtual machines and containers) the frequency fields are
None and CPU throttling cannot be judged.

Memory sizes are in MiB (2**20 bytes). The sampler measures its own cost: the wall time of one
sample, and the CPU time of its thread as a percentage of one core.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.replay.nvml import NvmlDevice

if TYPE_CHECKING:
    from types import TracebackType
    from typing import Self


__all__ = [
    'BUSY_CPU_PERCENT',
    'DEFAULT_INTERVAL_S',
    'DEFAULT_MAX_SAMPLES',
    'GPU_MEM_BASIS',
    'GPU_THROTTLE_REASONS',
    'ResourceSampler',
]

DEFAULT_INTERVAL_S = 0.1
DEFAULT_MAX_SAMPLES = 2000
#: Where the RSS is read; a missing folder makes the sampler use ``resource.getrusage``.
PROC_SELF = Path('/proc/self')
#: Where CPU frequencies (cpufreq) and thermal throttle counters are read.
SYS_CPU = Path('/sys/devices/system/cpu')
#: A sample's CPU frequency enters ``cpu_mhz_min`` / ``cpu_mhz_max`` only when the process used
#: at least this much CPU (percent of one core) over the interval before it: an idle CPU's
#: frequency falls by design and says nothing about throttling.
BUSY_CPU_PERCENT = 50.0
#: What ``gpu_mem_mb_pass_peak`` is, as the summary records it (``gpu_mem_basis``).
GPU_MEM_BASIS = (
    'NVML memory used on the whole device; gpu_mem_mb_pass_peak = gpu_mem_mb_peak - '
    "gpu_mem_mb_start, the device's memory at the start of this backend's pass (every backend "
    'of the run already open, those before it closed)'
)
#: NVML clock event reason bits that mean the GPU's clocks were held down (power cap, thermal or
#: hardware slowdown); idle, application clock settings, sync boost and display clocks are not.
GPU_THROTTLE_REASONS: dict[int, str] = {
    0x4: 'sw_power_cap',
    0x8: 'hw_slowdown',
    0x20: 'sw_thermal_slowdown',
    0x40: 'hw_thermal_slowdown',
    0x80: 'hw_power_brake_slowdown',
}
_MAX_CPUS = 256
_MIB = float(1 << 20)


class _Point(NamedTuple):
    """One sample, or several merged: values at time ``t_s`` since the start."""

    t_s: float
    cpu_s: float  # process CPU time since the start, cumulative
    rss_mb: float | None  # highest of the merged samples
    private_mb: float | None  # highest of the merged samples
    mapped_mb: float | None  # highest of the merged samples
    gpu_util: float | None  # mean of the merged samples
    gpu_mem_mb: float | None  # highest of the merged samples
    gpu_power_w: float | None  # mean of the merged samples
    cpu_mhz: float | None  # mean of the merged samples
    gpu_throttle: int | None  # every reason bit of the merged samples
    weight: int


def _mean(values: list[float | None], weights: list[int]) -> float | None:
    pairs = [(v, w) for v, w in zip(values, weights, strict=True) if v is not None]
    if not pairs:
        return None
    return sum(v * w for v, w in pairs) / sum(w for _, w in pairs)


def _max(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return max(present) if present else None


def _min(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return min(present) if present else None


def _bits(values: list[int | None]) -> int | None:
    present = [v for v in values if v is not None]
    if not present:
        return None
    merged = 0
    for value in present:
        merged |= value
    return merged


def _merge(points: list[_Point]) -> _Point:
    weights = [p.weight for p in points]
    last = points[-1]
    return _Point(
        t_s=last.t_s,
        cpu_s=last.cpu_s,
        rss_mb=_max([p.rss_mb for p in points]),
        private_mb=_max([p.private_mb for p in points]),
        mapped_mb=_max([p.mapped_mb for p in points]),
        gpu_util=_mean([p.gpu_util for p in points], weights),
        gpu_mem_mb=_max([p.gpu_mem_mb for p in points]),
        gpu_power_w=_mean([p.gpu_power_w for p in points], weights),
        cpu_mhz=_mean([p.cpu_mhz for p in points], weights),
        gpu_throttle=_bits([p.gpu_throttle for p in points]),
        weight=sum(weights),
    )


def _reduce(points: list[_Point], limit: int) -> list[_Point]:
    """Merge runs of consecutive points so that at most ``limit`` remain."""
    if len(points) <= limit:
        return list(points)
    size = math.ceil(len(points) / limit)
    return [_merge(points[i : i + size]) for i in range(0, len(points), size)]


class _Rss:
    """Memory in MiB: (resident, private, mapped) from ``/proc/self/statm``, else the peak
    resident size from getrusage and no private or mapped figure."""

    def __init__(self) -> None:
        self.fd: int | None = None
        self.source: str | None = None
        self.page = os.sysconf('SC_PAGE_SIZE') if hasattr(os, 'sysconf') else 4096
        try:
            self.fd = os.open(PROC_SELF / 'statm', os.O_RDONLY)
            self.source = 'statm'
        except OSError:
            try:
                import resource  # noqa: F401 - Unix only
            except ImportError:
                return
            self.source = 'getrusage_maxrss'

    def read(self) -> tuple[float | None, float | None, float | None]:
        if self.fd is not None:
            try:
                # size resident shared ...: shared = RssFile + RssShmem, resident - shared = RssAnon
                fields = os.pread(self.fd, 256, 0).split()
                resident, shared = int(fields[1]), int(fields[2])
            except (OSError, IndexError, ValueError):
                return None, None, None
            return (
                resident * self.page / _MIB,
                max(0, resident - shared) * self.page / _MIB,
                shared * self.page / _MIB,
            )
        if self.source == 'getrusage_maxrss':
            import resource

            peak = float(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
            # kilobytes on Linux and the BSDs, bytes on macOS
            return (peak / _MIB if sys.platform == 'darwin' else peak / 1024.0), None, None
        return None, None, None

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


class _CpuFreq:
    """The highest current frequency (MHz) of the CPUs this process may run on, from cpufreq,
    and the kernel's thermal throttle counters of those CPUs."""

    def __init__(self) -> None:
        try:
            cpus = sorted(os.sched_getaffinity(0))
        except (AttributeError, OSError):
            cpus = list(range(os.cpu_count() or 0))
        self.cpus = cpus[:_MAX_CPUS]
        self.fds: list[int] = []
        for cpu in self.cpus:
            try:
                self.fds.append(
                    os.open(SYS_CPU / f'cpu{cpu}' / 'cpufreq' / 'scaling_cur_freq', os.O_RDONLY)
                )
            except OSError:
                continue
        self.source = 'cpufreq' if self.fds else None
        self.throttle_start = self.throttle_count()

    def read(self) -> float | None:
        best: int | None = None
        for fd in self.fds:
            try:
                khz = int(os.pread(fd, 32, 0))
            except (OSError, ValueError):
                continue
            best = khz if best is None else max(best, khz)
        return None if best is None else best / 1000.0

    def throttle_count(self) -> int | None:
        """Core throttle events summed over the CPUs plus the most package events of any of
        them (a package counter is shared by its CPUs); None without thermal_throttle."""
        core = 0
        package = 0
        found = False
        for cpu in self.cpus:
            folder = SYS_CPU / f'cpu{cpu}' / 'thermal_throttle'
            for name in ('core_throttle_count', 'package_throttle_count'):
                try:
                    count = int((folder / name).read_text(encoding='ascii'))
                except (OSError, ValueError):
                    continue
                found = True
                if name == 'core_throttle_count':
                    core += count
                else:
                    package = max(package, count)
        return core + package if found else None

    def close(self) -> None:
        for fd in self.fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        self.fds = []


class ResourceSampler:
    """Sample this process every ``interval_s`` seconds in a daemon thread.

    Use as a context manager (or ``start()`` / ``stop()``) around the work to measure. A sample
    is also taken at the start and at the stop, so even short work has at least one interval.
    ``series()`` keeps at most ``max_samples`` points (consecutive samples are merged: CPU %
    over the merged span, the highest RSS and GPU memory, the mean GPU utilisation and power);
    the stored history stays below twice that however long the sampler runs. ``summary()`` is
    computed from every sample, not from the merged series.
    """

    def __init__(
        self,
        interval_s: float = DEFAULT_INTERVAL_S,
        gpu_index: int | None = None,
        max_samples: int = DEFAULT_MAX_SAMPLES,
    ) -> None:
        if not interval_s > 0:
            msg = f'interval_s must be positive, not {interval_s}'
            raise ValueError(msg)
        if max_samples < 2:
            msg = f'max_samples must be at least 2, not {max_samples}'
            raise ValueError(msg)
        self.interval_s = float(interval_s)
        self.gpu_index = gpu_index
        self.max_samples = max_samples
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rss: _Rss | None = None
        self._gpu: NvmlDevice | None = None
        self._freq: _CpuFreq | None = None
        self._points: list[_Point] = []  # each merges ``_stride`` samples
        self._pending: list[_Point] = []  # samples not yet merged into a point
        self._stride = 1
        self._t0 = 0.0
        self._cpu0 = 0
        self._last_t = 0.0
        self._last_cpu = 0.0
        self._stopped_at: float | None = None
        # running statistics over every sample
        self._samples = 0
        self._cpu_max: float | None = None
        self._rss_sum = 0.0
        self._rss_n = 0
        self._rss_peak: float | None = None
        self._private_sum = 0.0
        self._private_n = 0
        self._private_peak: float | None = None
        self._mapped_peak: float | None = None
        self._gpu_util_sum = 0.0
        self._gpu_util_n = 0
        self._gpu_mem_peak: float | None = None
        self._gpu_mem_start: float | None = None
        self._gpu_power_sum = 0.0
        self._gpu_power_n = 0
        self._cost_s = 0.0
        self._cost_n = 0
        self._thread_cpu_s = 0.0
        self._cpu_mhz_min: float | None = None
        self._cpu_mhz_max: float | None = None
        self._gpu_reasons: int | None = None
        self._throttle_events: int | None = None

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> Self:
        """Take the first sample and start the thread."""
        if self._thread is not None:
            msg = 'a ResourceSampler can be started once'
            raise RuntimeError(msg)
        self._rss = _Rss()
        self._gpu = NvmlDevice.open(self.gpu_index)
        self._freq = _CpuFreq()
        self._t0 = time.perf_counter()
        self._cpu0 = time.process_time_ns()
        self._take(timed=False)
        self._thread = threading.Thread(
            target=self._loop, name='replaybench-resources', daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and take the last sample; a second call does nothing."""
        if self._thread is None or self._stopped_at is not None:
            return
        self._stop.set()
        self._thread.join()
        self._take(timed=False)
        self._stopped_at = time.perf_counter()
        if self._rss is not None:
            self._rss.close()
        if self._gpu is not None:
            self._gpu.close()
        if self._freq is not None:
            end = self._freq.throttle_count()
            start = self._freq.throttle_start
            if start is not None and end is not None:
                self._throttle_events = max(0, end - start)
            self._freq.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def _loop(self) -> None:
        cpu_start = time.thread_time()
        next_t = self._t0 + self.interval_s
        while not self._stop.wait(max(0.0, next_t - time.perf_counter())):
            self._take(timed=True)
            next_t += self.interval_s
            now = time.perf_counter()
            if next_t < now:  # fell behind (a stalled machine): skip, do not burst
                next_t = now + self.interval_s
        self._thread_cpu_s = time.thread_time() - cpu_start

    # ------------------------------------------------------------------ sampling

    def _take(self, *, timed: bool) -> None:
        begin = time.perf_counter()
        cpu_s = (time.process_time_ns() - self._cpu0) / 1e9
        rss, private, mapped = self._rss.read() if self._rss is not None else (None, None, None)
        util = mem = power = None
        reasons = None
        if self._gpu is not None:
            util, mem, power = self._gpu.read()
            reasons = self._gpu.reasons()
        mhz = self._freq.read() if self._freq is not None else None
        t_s = time.perf_counter() - self._t0
        point = _Point(t_s, cpu_s, rss, private, mapped, util, mem, power, mhz, reasons, 1)
        with self._lock:
            span = t_s - self._last_t
            if self._samples and span >= 0.25 * self.interval_s:
                percent = 100.0 * (cpu_s - self._last_cpu) / span
                self._cpu_max = percent if self._cpu_max is None else max(self._cpu_max, percent)
                if mhz is not None and percent >= BUSY_CPU_PERCENT:
                    self._cpu_mhz_min = _min([self._cpu_mhz_min, mhz])
                    self._cpu_mhz_max = _max([self._cpu_mhz_max, mhz])
            if reasons is not None:
                self._gpu_reasons = _bits([self._gpu_reasons, reasons])
            self._last_t, self._last_cpu = t_s, cpu_s
            self._samples += 1
            if rss is not None:
                self._rss_sum += rss
                self._rss_n += 1
                self._rss_peak = rss if self._rss_peak is None else max(self._rss_peak, rss)
            if private is not None:
                self._private_sum += private
                self._private_n += 1
                self._private_peak = _max([self._private_peak, private])
            if mapped is not None:
                self._mapped_peak = _max([self._mapped_peak, mapped])
            if util is not None:
                self._gpu_util_sum += util
                self._gpu_util_n += 1
            if mem is not None:
                self._gpu_mem_peak = (
                    mem if self._gpu_mem_peak is None else max(self._gpu_mem_peak, mem)
                )
                if self._gpu_mem_start is None:  # the first reading: the start of the pass
                    self._gpu_mem_start = mem
            if power is not None:
                self._gpu_power_sum += power
                self._gpu_power_n += 1
            self._pending.append(point)
            if len(self._pending) >= self._stride:
                self._points.append(_merge(self._pending))
                self._pending = []
            if len(self._points) >= 2 * self.max_samples:
                # merge pairs and from now on whole pairs: every point spans as many samples
                self._points = _reduce(self._points, self.max_samples)
                self._stride *= 2
            if timed:
                self._cost_s += time.perf_counter() - begin
                self._cost_n += 1

    # ------------------------------------------------------------------ results

    def summary(self) -> dict[str, Any]:
        """Statistics over every sample so far (see docs/outputs.md, ``resources``)."""
        with self._lock:
            end = self._stopped_at if self._stopped_at is not None else time.perf_counter()
            duration = end - self._t0 if self._samples else 0.0
            cpu_mean = 100.0 * self._last_cpu / self._last_t if self._last_t > 0 else None
            running = self._thread is not None and self._stopped_at is None
            return {
                'cpu_percent_mean': cpu_mean,
                'cpu_percent_max': self._cpu_max if self._cpu_max is not None else cpu_mean,
                'private_mb_peak': self._private_peak,
                'private_mb_mean': self._private_sum / self._private_n if self._private_n else None,
                'mapped_mb_peak': self._mapped_peak,
                'rss_mb_peak': self._rss_peak,
                'rss_mb_mean': self._rss_sum / self._rss_n if self._rss_n else None,
                'gpu_util_mean': self._gpu_util_sum / self._gpu_util_n
                if self._gpu_util_n
                else None,
                'gpu_mem_mb_peak': self._gpu_mem_peak,
                'gpu_mem_mb_start': self._gpu_mem_start,
                'gpu_mem_mb_pass_peak': None
                if self._gpu_mem_peak is None or self._gpu_mem_start is None
                else self._gpu_mem_peak - self._gpu_mem_start,
                'gpu_mem_basis': GPU_MEM_BASIS if self._gpu_mem_start is not None else None,
                'gpu_power_w_mean': self._gpu_power_sum / self._gpu_power_n
                if self._gpu_power_n
                else None,
                'samples': self._samples,
                'interval_s': self.interval_s,
                'overhead_ms_per_sample': 1e3 * self._cost_s / self._cost_n
                if self._cost_n
                else None,
                'overhead_cpu_percent': 100.0 * self._thread_cpu_s / duration
                if duration > 0 and not running
                else None,
                'duration_s': duration,
                'cpu_source': 'process_time',
                'rss_source': self._rss.source if self._rss is not None else None,
                'gpu_index': self._gpu.index if self._gpu is not None else None,
                'gpu_name': self._gpu.name if self._gpu is not None else None,
                'gpu_uuid': self._gpu.uuid if self._gpu is not None else None,
                'gpu_pci_bus_id': self._gpu.pci_bus_id if self._gpu is not None else None,
                'gpu_match': self._gpu.match if self._gpu is not None else None,
                'cpu_mhz_min': self._cpu_mhz_min,
                'cpu_mhz_max': self._cpu_mhz_max,
                'cpu_freq_source': self._freq.source if self._freq is not None else None,
                'cpu_throttle_events': self._throttle_events,
                'gpu_throttle_reasons': None
                if self._gpu_reasons is None
                else [
                    name for bit, name in GPU_THROTTLE_REASONS.items() if self._gpu_reasons & bit
                ],
            }

    def series(self) -> list[dict[str, float | None]]:
        """The samples over time, at most ``max_samples``; ``cpu_percent`` over each span."""
        with self._lock:
            points = self._points + ([_merge(self._pending)] if self._pending else [])
        points = _reduce(points, self.max_samples)
        out: list[dict[str, float | None]] = []
        prev_t, prev_cpu = 0.0, 0.0
        shortest = 0.25 * self.interval_s
        for p in points:
            span = p.t_s - prev_t
            out.append(
                {
                    't_s': p.t_s,
                    # None for spans too short to mean anything (the sample taken at the start)
                    'cpu_percent': 100.0 * (p.cpu_s - prev_cpu) / span
                    if span >= shortest
                    else None,
                    'private_mb': p.private_mb,
                    'mapped_mb': p.mapped_mb,
                    'rss_mb': p.rss_mb,
                    'gpu_util': p.gpu_util,
                    'gpu_mem_mb': p.gpu_mem_mb,
                    'gpu_power_w': p.gpu_power_w,
                    'cpu_mhz': p.cpu_mhz,
                    'gpu_throttle': p.gpu_throttle,
                }
            )
            prev_t, prev_cpu = p.t_s, p.cpu_s
        return out
