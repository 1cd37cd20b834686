"""``stop_on_signals``: the command line's Ctrl-C / SIGTERM handling, opt-in and restored."""

from __future__ import annotations

import signal
import threading

import pytest

from replaybench.app.signals import stop_on_signals
from replaybench.errors import RunAborted


def test_the_first_signal_sets_the_token_and_the_handlers_are_restored_after():
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    token = threading.Event()
    with stop_on_signals(token):
        assert signal.getsignal(signal.SIGINT) is not before[signal.SIGINT]
        signal.raise_signal(signal.SIGTERM)
        assert token.is_set()
    assert {s: signal.getsignal(s) for s in before} == before


def test_a_second_signal_stops_at_once():
    token = threading.Event()
    with pytest.raises(RunAborted), stop_on_signals(token):  # noqa: PT012  the exception passes through the context manager under test
        signal.raise_signal(signal.SIGINT)
        assert token.is_set()
        signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_outside_the_main_thread_nothing_is_installed():
    token = threading.Event()
    seen: list[object] = []

    def worker() -> None:
        with stop_on_signals(token):
            seen.append(signal.getsignal(signal.SIGINT))

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert seen == [signal.default_int_handler]
    assert not token.is_set()
