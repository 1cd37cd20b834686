"""The replay engine: rates, clocks, the queueing scheduler, thread limits and the run."""

from replaybench.replay.clock import Clock, MonotonicClock, VirtualClock
from replaybench.replay.rate import Rate, parse_rate
from replaybench.replay.scheduler import replay_timed

__all__ = ['Clock', 'MonotonicClock', 'Rate', 'VirtualClock', 'parse_rate', 'replay_timed']
