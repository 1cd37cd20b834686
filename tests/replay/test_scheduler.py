from __future__ import annotations

from typing import Any

import pytest

from replaybench.errors import UsageError
from replaybench.replay import Rate, VirtualClock, parse_rate, replay_timed


def _simulate(offsets, service_s, depth, keys=None):
    clock = VirtualClock()
    events: list[tuple[Any, ...]] = []

    def process(item, release, start):
        clock.advance(service_s)
        events.append(('ok', item, release, start, clock.now()))

    def drop(item, release):
        events.append(('drop', item, release))

    keys = keys or ['a'] * len(offsets)
    replay_timed(
        ((o, k, i) for i, (o, k) in enumerate(zip(offsets, keys, strict=True))),
        clock=clock,
        queue_depth=depth,
        process=process,
        drop=drop,
    )
    return events


def test_a_backend_faster_than_the_frame_rate_drops_nothing():
    events = _simulate([i * 0.1 for i in range(20)], service_s=0.05, depth=1)
    assert [e[0] for e in events] == ['ok'] * 20
    assert all(e[3] == pytest.approx(e[2]) for e in events)  # never waits


def test_a_backend_slower_than_the_frame_rate_drops_exactly_the_pushed_out_frames():
    # 10 Hz frames, 0.25 s service, depth 1: frame 0 runs 0-0.25; 1 and 2 arrive, 2 pushes out 1;
    # 2 runs 0.25-0.5 while 3, 4, 5 arrive (5 stays) ... a deterministic pattern.
    offsets = [i * 0.1 for i in range(10)]
    events = _simulate(offsets, service_s=0.25, depth=1)
    done = [e[1] for e in events if e[0] == 'ok']
    dropped = [e[1] for e in events if e[0] == 'drop']
    assert done == [0, 2, 5, 7, 9]
    assert dropped == [1, 3, 4, 6, 8]
    assert sorted(done + dropped) == list(range(10))


def test_a_deeper_queue_keeps_more_frames_and_adds_queue_wait():
    offsets = [i * 0.1 for i in range(10)]
    shallow = _simulate(offsets, service_s=0.15, depth=1)
    deep = _simulate(offsets, service_s=0.15, depth=3)
    assert sum(e[0] == 'drop' for e in deep) < sum(e[0] == 'drop' for e in shallow)
    waits = [e[3] - e[2] for e in deep if e[0] == 'ok']
    assert max(waits) > 0.1


def test_queues_are_per_topic_so_one_camera_does_not_push_out_another():
    offsets = [0.0, 0.0, 0.01, 0.01]
    keys = ['left', 'right', 'left', 'right']
    events = _simulate(offsets, service_s=0.5, depth=1, keys=keys)
    dropped = sorted(e[1] for e in events if e[0] == 'drop')
    # left 0 is processed at once; right 1 is pushed out by right 3; left 2 waits; nothing else lost
    assert dropped == [1]
    assert sorted(e[1] for e in events if e[0] == 'ok') == [0, 2, 3]


def test_waiting_frames_are_served_oldest_release_first():
    events = _simulate([0.0, 0.01, 0.02], service_s=1.0, depth=1, keys=['a', 'b', 'c'])
    assert [e[1] for e in events if e[0] == 'ok'] == [0, 1, 2]


def test_every_frame_is_either_processed_or_dropped_once():
    offsets = [i / 30 for i in range(300)]
    events = _simulate(offsets, service_s=0.047, depth=2)
    ids = sorted(e[1] for e in events)
    assert ids == list(range(300))


@pytest.mark.parametrize(
    ('text', 'rate'),
    [
        ('max', Rate('max')),
        ('recorded', Rate('recorded')),
        ('2x', Rate('recorded', scale=2.0)),
        ('0.5x', Rate('recorded', scale=0.5)),
        ('30hz', Rate('fixed', hz=30.0)),
        ('12.5Hz', Rate('fixed', hz=12.5)),
    ],
)
def test_rates_parse_from_the_names_users_type(text, rate):
    assert parse_rate(text) == rate
    assert parse_rate(str(rate)) == rate


@pytest.mark.parametrize('text', ['fast', '0x', '-1x', 'hz', '30 fps', ''])
def test_a_bad_rate_is_a_usage_error(text):
    with pytest.raises(UsageError, match='invalid rate'):
        parse_rate(text)
