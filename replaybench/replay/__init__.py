"""The replay engine: rates, clocks, the queueing scheduler, thread limits and the run."""

from replaybench.replay.clock import Clock, MonotonicClock, ThreadVirtualClock, VirtualClock
from replaybench.replay.rate import Rate, parse_rate
from replaybench.replay.scheduler import Lane, replay_lanes, replay_timed

__all__ = [
    'Clock',
    'Lane',
    'MonotonicClock',
    'Rate',
    'ThreadVirtualClock',
    'VirtualClock',
    'parse_rate',
    'replay_lanes',
    'replay_timed',
]
