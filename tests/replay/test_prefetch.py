from __future__ import annotations

import threading

import pytest

from replaybench.errors import SourceError
from replaybench.replay import MonotonicClock
from replaybench.replay.prefetch import Prefetcher
from replaybench.types import RawMessage


def _raw(seq: int) -> RawMessage:
    return RawMessage('/cam/image_raw', 'sensor_msgs/msg/Image', 'cdr', seq, seq, b'not an image')


def test_prefetched_items_come_in_order_with_decode_failures_kept():
    with Prefetcher(iter([_raw(i) for i in range(20)]), MonotonicClock(), depth=3) as items:
        got = list(items)
    assert [p.raw.seq for p in got] == list(range(20))
    assert all(p.read_decode_s >= 0 for p in got)
    assert all(not hasattr(p.decoded, 'image') for p in got)  # every one is a DecodeError


def test_the_reader_stays_at_most_depth_frames_ahead():
    pulled: list[int] = []
    gate = threading.Event()

    def messages():
        for i in range(50):
            pulled.append(i)
            yield _raw(i)

    with Prefetcher(messages(), MonotonicClock(), depth=2) as items:
        first = next(items)
        gate.wait(0.3)
        # one handed out, two buffered, one read and waiting for room
        assert len(pulled) <= 1 + 2 + 1
        assert first.raw.seq == 0


def test_a_reader_error_reaches_the_consumer():
    def messages():
        yield _raw(0)
        msg = 'file cut short'
        raise SourceError(msg)

    with Prefetcher(messages(), MonotonicClock(), depth=2) as items:
        assert next(items).raw.seq == 0
        with pytest.raises(SourceError, match='cut short'):
            next(items)


def test_leaving_early_stops_the_reader_thread():
    before = threading.active_count()
    with Prefetcher(iter([_raw(i) for i in range(1000)]), MonotonicClock(), depth=2) as items:
        next(items)
    assert threading.active_count() == before
