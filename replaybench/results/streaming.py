"""What the run's outputs show of its streaming scores (``replaybench.replay.streaming``): each
streaming metric beside the offline figure it is the streaming form of, and the distribution of
the output age (frames.csv's ``output_age_ms``) of each (backend, topic)."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from replaybench.results.model import SummaryRow
    from replaybench.results.records import FrameRecord

__all__ = ['AgeSpread', 'StreamingPair', 'output_ages', 'streaming_pairs']


class AgeSpread(NamedTuple):
    """The output ages (ms) of a (backend, topic)'s frames that had an output in use: how many,
    their median, 90th percentile and largest, and the frames that had none yet."""

    frames: int
    p50_ms: float
    p90_ms: float
    max_ms: float
    without: int


class StreamingPair(NamedTuple):
    """A row's streaming metric (``name``, its ``label``) and the offline figure it is the
    streaming form of (``offline``), with both values; ``change`` = streaming - offline."""

    name: str
    label: str
    offline_value: float
    value: float

    @property
    def change(self) -> float:
        return self.value - self.offline_value


def _quantile(ordered: list[float], q: float) -> float:
    """Linear interpolation between order statistics (numpy's default)."""
    at = (len(ordered) - 1) * q
    low = int(at)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (at - low)


def output_ages(records: Iterable[FrameRecord]) -> dict[tuple[str, str], AgeSpread]:
    """The ``AgeSpread`` of each (backend, topic) whose frames have output ages (first pass;
    timed rates and recorded outputs), in the order first met."""
    ages: dict[tuple[str, str], list[float]] = {}
    without: dict[tuple[str, str], int] = {}
    timed: set[tuple[str, str]] = set()
    for r in records:
        if r.repeat:
            continue
        key = (r.backend, r.topic)
        if r.output_age_ms is None:
            without[key] = without.get(key, 0) + 1
        else:
            timed.add(key)
            ages.setdefault(key, []).append(r.output_age_ms)
    out: dict[tuple[str, str], AgeSpread] = {}
    for key, found in ages.items():
        ordered = sorted(found)
        out[key] = AgeSpread(
            len(ordered),
            _quantile(ordered, 0.5),
            _quantile(ordered, 0.9),
            ordered[-1],
            without.get(key, 0),
        )
    return out


def streaming_pairs(
    row: SummaryRow, offline_of: Mapping[str, tuple[str, str]]
) -> list[StreamingPair]:
    """The row's streaming metrics that have a value and whose offline figure has one too;
    ``offline_of``: streaming metric name -> (its label, the offline figure's name)."""
    found: list[StreamingPair] = []
    for name, (label, offline) in offline_of.items():
        value, before = row.metric(name), row.metric(offline)
        if value is not None and before is not None:
            found.append(StreamingPair(name, label, before, value))
    return found
