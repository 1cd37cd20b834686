"""Clocks the scheduler runs on: the real monotonic clock, and a virtual one for tests."""

from __future__ import annotations

import threading
import time
from typing import Protocol

__all__ = ['Clock', 'MonotonicClock', 'ThreadVirtualClock', 'VirtualClock']


class Clock(Protocol):
    """Seconds on a monotonic time line, and a way to wait for a point on it."""

    def now(self) -> float: ...

    def sleep_until(self, t: float) -> None: ...


class MonotonicClock:
    """``time.perf_counter``; ``sleep_until`` sleeps, then spins the last half millisecond."""

    #: the builtin itself, not a method wrapping it: the replay reads the clock twice a frame
    now = staticmethod(time.perf_counter)

    def sleep_until(self, t: float) -> None:
        while True:
            left = t - time.perf_counter()
            if left <= 0:
                return
            if left > 0.0015:
                time.sleep(left - 0.001)


class VirtualClock:
    """A clock that moves only when told to: ``sleep_until`` jumps, ``advance`` adds."""

    def __init__(self, start: float = 0.0) -> None:
        self._t = start

    def now(self) -> float:
        return self._t

    def sleep_until(self, t: float) -> None:
        self._t = max(self._t, t)

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` pass, as a backend of declared service time does inside ``detect``."""
        self._t += seconds


class ThreadVirtualClock:
    """A virtual clock with one time line per thread: each thread's starts at ``start`` and
    moves only when that thread tells it to. The per-topic pipelines
    (``replaybench.replay.scheduler.replay_lanes``) run one worker thread each, as machines of
    their own: on this clock each worker's times depend on its own frames only, whatever the
    threads' interleaving, so a per-topic replay is as exact and testable as a shared one."""

    def __init__(self, start: float = 0.0) -> None:
        self._start = start
        self._line = threading.local()

    def now(self) -> float:
        t: float = getattr(self._line, 't', self._start)
        return t

    def sleep_until(self, t: float) -> None:
        self._line.t = max(self.now(), t)

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` pass on the calling thread's time line."""
        self._line.t = self.now() + seconds
