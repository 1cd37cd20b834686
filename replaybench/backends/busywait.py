"""The busy backend: spins for a set time per frame and detects nothing — a backend of known cost.

It exists to measure the harness and its statistics against a known truth: with ``ms = 10`` a
frame costs 10 ms of the backend's time, so a peak sweep must find about 100 Hz and a
comparison of 10 ms against 13 ms must find +30 %.

Options (``BackendOptions.extra`` keys, or the keys of a ``--config`` TOML file; ``extra``
wins): ``busy_ms`` (TOML ``ms``) the time spun per frame in milliseconds, default 10;
``busy_clock`` (TOML ``clock``) what that time is measured on:

- ``wall`` (default): the monotonic clock (``time.perf_counter``). A frame costs ``ms`` of
  wall time whatever else runs (plus the time the thread waits for a CPU once it is due):
  a fixed service time, as a device that takes a fixed time per frame.
- ``cpu``: the calling thread's CPU time (``time.thread_time``). A frame costs ``ms`` of
  computation, so it takes longer when other processes share the CPU, as a compute-bound
  detector does.
"""

from __future__ import annotations

import contextlib
import math
import time
import tomllib
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import BackendError
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping
    from pathlib import Path

    from replaybench.types import Frame

__all__ = ['CLOCKS', 'DEFAULT_MS', 'MAX_MS', 'BusyBackend', 'spin_options']

#: Time spun per frame when no option sets it.
DEFAULT_MS = 10.0
#: The largest accepted cost per frame (one minute).
MAX_MS = 60_000.0
#: What ``busy_clock`` may name, and the clock each reads.
CLOCKS: dict[str, Callable[[], float]] = {'wall': time.perf_counter, 'cpu': time.thread_time}

_TOML_KEYS = {'ms': 'busy_ms', 'clock': 'busy_clock'}


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open('rb') as f:
            table = tomllib.load(f)
    except OSError as err:
        msg = f'busy backend: cannot read {path}: {err.strerror or err}'
        raise BackendError(msg) from err
    except tomllib.TOMLDecodeError as err:
        msg = f'busy backend: {path} is not valid TOML: {err}'
        raise BackendError(msg) from err
    unknown = sorted(set(table) - set(_TOML_KEYS))
    if unknown:
        msg = f'busy backend: {path}: unknown key {unknown[0]!r} (known: clock, ms)'
        raise BackendError(msg)
    return {_TOML_KEYS[k]: v for k, v in table.items()}


def _settings(options: BackendOptions) -> tuple[float, str]:
    given: dict[str, Any] = _read_toml(options.config) if options.config is not None else {}
    unknown = sorted(set(options.extra) - set(_TOML_KEYS.values()))
    if unknown:
        msg = f'busy backend: unknown option {unknown[0]!r} (known: busy_clock, busy_ms)'
        raise BackendError(msg)
    given.update(options.extra)
    ms = given.get('busy_ms', DEFAULT_MS)
    if isinstance(ms, str):
        with contextlib.suppress(ValueError):
            ms = float(ms)
    if isinstance(ms, bool) or not isinstance(ms, int | float) or not math.isfinite(ms):
        msg = f'busy backend: busy_ms must be a number of milliseconds, not {ms!r}'
        raise BackendError(msg)
    if not 0 <= ms <= MAX_MS:
        msg = f'busy backend: busy_ms must be between 0 and {MAX_MS:g}, not {ms:g}'
        raise BackendError(msg)
    clock = given.get('busy_clock', 'wall')
    if clock not in CLOCKS:
        msg = f'busy backend: busy_clock must be wall or cpu, not {clock!r}'
        raise BackendError(msg)
    return float(ms), str(clock)


class BusyBackend:
    """Spins ``busy_ms`` milliseconds of wall or CPU time per frame; returns no detections."""

    name: ClassVar[str] = 'busy'
    #: ``detect`` never reads ``frame.camera_info``.
    reads_camera_info: ClassVar[bool] = False
    description: ClassVar[str] = (
        'spins a set time per frame (busy_ms, default 10) and detects nothing: a known cost'
    )

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        self.ms, self.clock_name = _settings(self.options)
        self._clock = CLOCKS[self.clock_name]
        self._seconds = self.ms / 1e3

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def open(self) -> None:
        """Nothing to load."""

    def detect(self, frame: Frame) -> BackendResult:  # noqa: ARG002  the protocol's signature
        clock = self._clock
        start = clock()
        end = start + self._seconds
        now = start
        while now < end:
            now = clock()
        spun = round((now - start) * 1e9)
        return BackendResult((), StageTimes(preprocess_ns=0, infer_ns=spun, postprocess_ns=0))

    def info(self) -> dict[str, Any]:
        return {'busy_ms': self.ms, 'busy_clock': self.clock_name, 'detections': 'none'}

    def close(self) -> None:
        """Nothing to release."""


def spin_options(ms: float, clock: str = 'wall') -> Mapping[str, str]:
    """``BackendOptions.extra`` for a busy backend of ``ms`` per frame on ``clock``."""
    return {'busy_ms': repr(float(ms)), 'busy_clock': clock}
