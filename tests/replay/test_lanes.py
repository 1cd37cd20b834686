"""``replay_lanes``: one pipeline per camera, each in a worker of its own, on a virtual clock.

The calibrated case of docs/rigs.md: a backend that waits 20 ms per frame without using the
CPU, four cameras at 30 Hz. One shared backend can serve at most 50 of the 120 frames a second
(drops of at least 55 %); one backend per camera serves them all.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.replay import Lane, ThreadVirtualClock, VirtualClock, replay_lanes, replay_timed

if TYPE_CHECKING:
    from collections.abc import Sequence

CAMERAS = [f'/rig/cam{j}' for j in range(4)]
HZ = 30.0
SERVICE_S = 0.020
SECONDS = 4


def _rig_releases(cameras: list[str], frames: int) -> list[tuple[float, str, tuple[str, int]]]:
    """Hardware-synchronised: frame i of every camera released at i / 30 s."""
    return [(i / HZ, cam, (cam, i)) for i in range(frames) for cam in cameras]


def _shared(releases: list[tuple[float, str, Any]], service_s: float) -> tuple[int, int]:
    clock = VirtualClock()
    done, dropped = [0], [0]

    def process(_item: Any, _release: float, _start: float) -> None:
        clock.advance(service_s)
        done[0] += 1

    def drop(_item: Any, _release: float) -> None:
        dropped[0] += 1

    replay_timed(releases, clock=clock, queue_depth=1, process=process, drop=drop)
    return done[0], dropped[0]


def _per_topic(
    releases: Sequence[tuple[float | None, str, Any]], service_s: float, depth: int = 1
) -> dict[str, list[tuple[str, Any, float, float, float]]]:
    clock = ThreadVirtualClock()
    events: dict[str, list[tuple[str, Any, float, float, float]]] = {c: [] for c in CAMERAS}
    threads: dict[str, set[str]] = {c: set() for c in CAMERAS}

    def lane(cam: str) -> Lane[Any]:
        def process(item: Any, release: float, start: float) -> None:
            threads[cam].add(threading.current_thread().name)
            clock.advance(service_s)
            events[cam].append(('ok', item, release, start, clock.now()))

        def drop(item: Any, release: float) -> None:
            events[cam].append(('drop', item, release, release, release))

        return Lane(process, drop)

    replay_lanes(releases, {c: lane(c) for c in CAMERAS}, clock=clock, queue_depth=depth, start=0.0)
    assert all(len(names) == 1 for names in threads.values())  # one worker per camera
    assert len(set().union(*threads.values())) == len(CAMERAS)
    return events


def test_one_shared_backend_of_20_ms_serves_at_most_50_of_the_120_frames_a_second() -> None:
    releases = _rig_releases(CAMERAS, int(SECONDS * HZ))
    done, dropped = _shared(releases, SERVICE_S)
    assert done + dropped == len(releases) == 480
    # 50 a second while frames arrive, then the one left in each camera's queue at the end
    assert done <= 50 * SECONDS + len(CAMERAS)
    assert dropped / len(releases) >= 0.55


def test_one_backend_per_camera_of_20_ms_serves_every_frame_of_four_cameras_at_30_hz() -> None:
    releases = _rig_releases(CAMERAS, int(SECONDS * HZ))
    events = _per_topic(releases, SERVICE_S)
    kinds = [e[0] for cam in CAMERAS for e in events[cam]]
    assert len(kinds) == 480
    assert kinds.count('drop') / len(kinds) <= 0.01
    for cam in CAMERAS:
        # each camera's frames in order, each released at its own time and served at once
        assert [e[1] for e in events[cam]] == [(cam, i) for i in range(int(SECONDS * HZ))]
        for _, (_, i), release, start, done in events[cam]:
            assert release == pytest.approx(i / HZ)
            assert start == pytest.approx(release)
            assert done == pytest.approx(release + SERVICE_S)


def test_a_lane_slower_than_its_camera_drops_only_its_own_frames() -> None:
    # the same pattern as one queue of replay_timed: 10 Hz, 0.25 s, depth 1 -> 0 2 5 7 9 kept
    releases = [(i * 0.1, cam, i) for i in range(10) for cam in CAMERAS]
    slow = {CAMERAS[0]}
    clock = ThreadVirtualClock()
    kept: dict[str, list[int]] = {c: [] for c in CAMERAS}

    def lane(cam: str) -> Lane[int]:
        def process(item: int, _release: float, _start: float) -> None:
            clock.advance(0.25 if cam in slow else 0.05)
            kept[cam].append(item)

        return Lane(process, lambda item, release: None)

    replay_lanes(releases, {c: lane(c) for c in CAMERAS}, clock=clock, queue_depth=1, start=0.0)
    assert kept[CAMERAS[0]] == [0, 2, 5, 7, 9]
    assert all(kept[c] == list(range(10)) for c in CAMERAS[1:])


def test_at_the_max_rate_each_lane_serves_its_frames_back_to_back() -> None:
    releases: list[tuple[float | None, str, Any]] = [
        (None, cam, (cam, i)) for i in range(5) for cam in CAMERAS
    ]
    events = _per_topic(releases, SERVICE_S)
    for cam in CAMERAS:
        starts = [e[3] for e in events[cam]]
        assert starts == pytest.approx([i * SERVICE_S for i in range(5)])
        assert [e[0] for e in events[cam]] == ['ok'] * 5


def test_what_a_lane_raises_stops_every_lane_and_is_raised_to_the_reader() -> None:
    clock = ThreadVirtualClock()
    served: list[int] = []

    def failing(item: int, _release: float, _start: float) -> None:
        if item == 3:
            msg = 'detector broke'
            raise RuntimeError(msg)
        clock.advance(0.01)
        served.append(item)

    def fine(_item: int, _release: float, _start: float) -> None:
        clock.advance(0.01)

    releases = ((i * 0.1, cam, i) for i in range(10_000) for cam in ('a', 'b'))
    with pytest.raises(RuntimeError, match='detector broke'):
        replay_lanes(
            releases,
            {'a': Lane(failing, lambda i, r: None), 'b': Lane(fine, lambda i, r: None)},
            clock=clock,
            queue_depth=1,
            start=0.0,
            feed_depth=4,
        )
    assert served == [0, 1, 2]


def test_what_reading_raises_ends_the_lanes_and_is_raised() -> None:
    clock = ThreadVirtualClock()

    def releases() -> Any:
        yield (0.0, 'a', 0)
        msg = 'stopped'
        raise KeyboardInterrupt(msg)

    with pytest.raises(KeyboardInterrupt):
        replay_lanes(
            releases(),
            {'a': Lane(lambda i, r, s: clock.advance(0.01), lambda i, r: None)},
            clock=clock,
            queue_depth=1,
            start=0.0,
        )
    assert threading.active_count() == 1 or all(
        not t.name.startswith('lane ') for t in threading.enumerate()
    )
