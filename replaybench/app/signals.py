"""Ctrl-C and SIGTERM for the command line: opt-in, never installed by a library call.

The engine stops through a cancellation token (a ``threading.Event`` passed as ``stop=``): it
looks at the token between frames, and when it is set ends the replay and finalises every output
with the frames done so far (status ``interrupted``). ``stop_on_signals`` is how the command
line sets that token; a Python program that wants the same sets the token itself (from a
thread, a timer, its own handler).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import TYPE_CHECKING, Any

from replaybench.errors import RunAborted

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

__all__ = ['STOP_SIGNALS', 'stop_on_signals']

#: The signals ``stop_on_signals`` handles.
STOP_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_on_signals(
    token: threading.Event, signals: Sequence[signal.Signals] = STOP_SIGNALS
) -> Iterator[threading.Event]:
    """Inside the block the first of ``signals`` sets ``token`` (the run stops at the next frame
    and finishes its outputs); another one raises ``RunAborted`` (stop at once, outputs not
    finished). The previous handlers are put back when the block ends. Outside the main
    thread, where Python cannot handle signals, nothing is installed."""
    if threading.current_thread() is not threading.main_thread():
        yield token
        return
    count = 0

    def handle(_signum: int, _frame: object) -> None:
        nonlocal count
        count += 1
        if count == 1:
            token.set()
            return
        raise RunAborted

    previous: dict[signal.Signals, Any] = {}
    try:
        for sig in signals:
            previous[sig] = signal.signal(sig, handle)
        yield token
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
