"""Recorded latency: when the robot's own perception produced each output, from the recording.

A bag recorded with live perception holds, for each camera image, the image (its header stamp
and its log time) and the output a node published for it (its log time; its header carries the
image's stamp, by which the ``recorded`` backend matches it). For every recorded output matched
to a replayed frame:

* ``capture_to_output_ms`` = output log time - image header stamp: from the moment the driver
  stamped the image (the sensor's capture or the driver's receipt, as the driver stamps it) to
  the moment the recorder logged the output. It holds the image's transport to the node, the
  node's own work (decode, inference, post-processing), the output's transport to the recorder
  and the recorder's own delay in logging it.
* ``pipeline_ms`` = output log time - image log time: from the recorder logging the image to
  the recorder logging the output. The image's transport and the recorder's delay appear on both
  sides and mostly cancel; it holds the node's work and the difference in transport between the
  two messages. It is the figure closest to a replayed backend's ``latency_ms``.

Both use the recorder's clock for the log times and the image's header stamp from the driver's
clock: capture-to-output is only meaningful when the two clocks agree. Values are refused (no
number, a note) when the stamps cannot support them (``recorded_times``):

* a zero header stamp: the image has no capture time, and outputs cannot be told apart by it
  (both figures refused);
* an output logged before its image: the clocks disagree or the output is matched to the wrong
  image (both refused);
* an image stamped after it was logged, or more than ``MAX_STAMP_AGE_S`` before: the driver's
  clock is not the recorder's (simulated time, an unsynchronised camera); capture-to-output
  refused.

The outputs are counted once, from the first pass, however many passes ``run --repeat`` makes:
every pass replays the same recorded outputs. A (backend, topic) figure is reported only when
none of its matched outputs was refused for it (``recorded_summary``): a clock that disagrees
for some frames makes every frame doubtful. The median and p99 get 95 % block-bootstrap
intervals as replayed latency does (``replaybench.results.intervals``), none below
``MIN_FRAMES`` outputs.
"""

from __future__ import annotations

import zlib
from dataclasses import replace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.results.bootstrap import (
    CONFIDENCE,
    DEFAULT_RESAMPLES,
    MIN_FRAMES,
    percentile_interval,
    replicates,
)
from replaybench.results.columns import RECORDED_COLUMNS
from replaybench.results.records import written

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import SummaryRow
    from replaybench.results.records import FrameRecord

__all__ = [
    'MAX_STAMP_AGE_S',
    'RECORDED_COLUMNS',
    'RECORDED_FIGURES',
    'RecordedTimes',
    'first_pass',
    'recorded_summary',
    'recorded_times',
    'replays_recording',
    'with_recorded_latency',
]

_NS = 1_000_000_000
#: An image stamped longer than this before it was logged is taken to carry another clock.
MAX_STAMP_AGE_S = 10.0

#: The two recorded latencies (frames.csv columns, summary column prefixes).
RECORDED_FIGURES: tuple[str, ...] = ('capture_to_output_ms', 'pipeline_ms')
_STATS: tuple[str, ...] = (
    'mean',
    'p50',
    'p50_ci_low',
    'p50_ci_high',
    'p99',
    'p99_ci_low',
    'p99_ci_high',
    'max',
)

# The summary.csv / run.json columns of the recorded latency, ``RECORDED_COLUMNS``, live in
# replaybench.results.columns with the other summary columns (and SummaryRow's fields): the
# counts, the rate, each figure's ``_STATS`` (``{figure}_{stat}``) and the note.

# why a value is refused: code -> what the note says of the outputs concerned
_REASONS: dict[str, str] = {
    'zero_stamp': 'have an image with a zero header stamp (no capture time to measure from)',
    'output_before_image': (
        'were logged before their image (the clocks disagree, or an output is matched to the '
        'wrong image)'
    ),
    'stamp_after_log': (
        "have an image stamped after it was logged (the camera's clock is not the recorder's)"
    ),
    'stamp_far': (
        f'have an image stamped more than {MAX_STAMP_AGE_S:g} s before it was logged (another '
        'time base, such as simulated time)'
    ),
}


class RecordedTimes(NamedTuple):
    """The recorded latencies of one frame (None: refused or no output) and why any is refused."""

    output_log_time_ns: int | None
    capture_to_output_ms: float | None
    pipeline_ms: float | None
    #: refusal codes (``_REASONS``); None where the value is given
    capture_refused: str | None = None
    pipeline_refused: str | None = None

    @property
    def note(self) -> str:
        """One line for frames.csv's note: '' when both values are given."""
        if self.output_log_time_ns is None:
            return 'no recorded output for this frame'
        if self.pipeline_refused is not None:
            return f'recorded latency refused: {_FRAME_REASONS[self.pipeline_refused]}'
        if self.capture_refused is not None:
            return f'capture-to-output refused: {_FRAME_REASONS[self.capture_refused]}'
        return ''


# the same reasons, of one frame's output
_FRAME_REASONS: dict[str, str] = {
    'zero_stamp': 'its image has a zero header stamp',
    'output_before_image': 'the output was logged before its image (the clocks disagree)',
    'stamp_after_log': "the image was stamped after it was logged (the camera's clock is not "
    "the recorder's)",
    'stamp_far': f'the image was stamped more than {MAX_STAMP_AGE_S:g} s before it was logged '
    '(another time base)',
}


def recorded_times(
    image_log_time_ns: int, image_stamp_ns: int | None, output_log_time_ns: int | None
) -> RecordedTimes:
    """Capture-to-output and pipeline latency of one frame (see the module docstring)."""
    if output_log_time_ns is None:
        return RecordedTimes(None, None, None)
    if not image_stamp_ns:
        return RecordedTimes(output_log_time_ns, None, None, 'zero_stamp', 'zero_stamp')
    if output_log_time_ns < image_log_time_ns:
        code = 'output_before_image'
        return RecordedTimes(output_log_time_ns, None, None, code, code)
    pipeline = (output_log_time_ns - image_log_time_ns) / 1e6
    age = image_log_time_ns - image_stamp_ns
    if age < 0:
        return RecordedTimes(output_log_time_ns, None, pipeline, 'stamp_after_log')
    if age > MAX_STAMP_AGE_S * _NS:
        return RecordedTimes(output_log_time_ns, None, pipeline, 'stamp_far')
    return RecordedTimes(output_log_time_ns, (output_log_time_ns - image_stamp_ns) / 1e6, pipeline)


def _is_recorded(records: Sequence[FrameRecord]) -> bool:
    """A (backend, topic) replaying recorded outputs: processed frames, none of them timed."""
    ok = [r for r in records if r.status == 'ok']
    return bool(ok) and all(r.latency_ms is None for r in ok)


def _rng(seed: int, backend: str, topic: str, figure: str) -> np.random.Generator:
    key = zlib.crc32(f'{backend}\0{topic}\0{figure}'.encode())
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0, key)))


def _figure(
    values: Sequence[float], backend: str, topic: str, figure: str, seed: int
) -> dict[str, float | None]:
    """mean, p50, p99, max and the 95 % intervals of p50 and p99 of one figure."""
    out: dict[str, float | None] = dict.fromkeys(f'{figure}_{stat}' for stat in _STATS)
    lat = np.asarray([written(v, figure) for v in values], dtype=np.float64)
    if not lat.size:
        return out
    p50, p99 = (float(v) for v in np.percentile(lat, (50, 99), method='linear'))
    out[f'{figure}_mean'] = float(lat.mean())
    out[f'{figure}_p50'] = p50
    out[f'{figure}_p99'] = p99
    out[f'{figure}_max'] = float(lat.max())
    reps = replicates(lat, None, n_boot=DEFAULT_RESAMPLES, rng=_rng(seed, backend, topic, figure))
    if reps is not None:
        for name, samples, point in (('p50', reps.p50, p50), ('p99', reps.p99, p99)):
            found = percentile_interval(samples, CONFIDENCE, point=point)
            if found is not None:
                out[f'{figure}_{name}_ci_low'], out[f'{figure}_{name}_ci_high'] = found
    return out


def _refusal(figure: str, refused: dict[str, int], matched: int) -> str:
    parts = [f'{n} of {matched} recorded outputs {_REASONS[code]}' for code, n in refused.items()]
    return f'{figure} not reported: ' + '; '.join(parts)


def first_pass(records: Sequence[FrameRecord]) -> list[FrameRecord]:
    """The measured frames of the first pass: each pass of ``--repeat`` replays the same
    recorded outputs, so they count once."""
    measured = [r for r in records if r.status == 'ok' and not r.warmup]
    first = min((r.repeat for r in measured), default=0)
    return [r for r in measured if r.repeat == first]


def recorded_summary(
    backend: str, topic: str, records: Sequence[FrameRecord], *, seed: int = 0
) -> dict[str, Any] | None:
    """The recorded-latency columns of one (backend, topic) (``RECORDED_COLUMNS``); None when
    it replays no recorded outputs (a replayed backend)."""
    if not _is_recorded(records):
        return None
    frames = sorted(first_pass(records), key=lambda r: written(r.release_s, 'release_s'))
    times = [recorded_times(r.log_time_ns, r.stamp_ns, r.output_log_time_ns) for r in frames]
    matched = [t for t in times if t.output_log_time_ns is not None]
    row: dict[str, Any] = dict.fromkeys(RECORDED_COLUMNS)
    row['recorded_outputs'] = len(matched)
    row['recorded_outputs_dropped'] = len(times) - len(matched)
    notes: list[str] = []
    logged = sorted({t.output_log_time_ns for t in matched if t.output_log_time_ns is not None})
    if len(logged) >= 2 and logged[-1] > logged[0]:
        row['recorded_output_hz'] = (len(logged) - 1) * _NS / (logged[-1] - logged[0])
    if not matched:
        notes.append('no recorded output matched a replayed frame')
    reported = 0
    for figure, label, value_of, refused_of in (
        ('pipeline_ms', 'pipeline latency', _pipeline, _pipeline_refused),
        ('capture_to_output_ms', 'capture-to-output latency', _capture, _capture_refused),
    ):
        refused: dict[str, int] = {}
        for t in matched:
            code = refused_of(t)
            if code is not None:
                refused[code] = refused.get(code, 0) + 1
        if refused:
            notes.append(_refusal(label, refused, len(matched)))
            continue
        values = [v for t in matched if (v := value_of(t)) is not None]
        row.update(_figure(values, backend, topic, figure, seed))
        reported += 1
    if reported and len(matched) < MIN_FRAMES:
        notes.append(f'{len(matched)} recorded outputs: fewer than {MIN_FRAMES}, no 95 % interval')
    row['recorded_latency_note'] = '; '.join(notes)
    return row


def _pipeline(t: RecordedTimes) -> float | None:
    return t.pipeline_ms


def _capture(t: RecordedTimes) -> float | None:
    return t.capture_to_output_ms


def _pipeline_refused(t: RecordedTimes) -> str | None:
    return t.pipeline_refused


def _capture_refused(t: RecordedTimes) -> str | None:
    return t.capture_refused


def replays_recording(row: SummaryRow) -> bool:
    """Whether a summary row is a backend replaying recorded outputs (``recorded``): its
    ``throughput_fps`` is how fast the bag was read, no detector's speed, and its latency is
    the recorded one (``recorded_output_hz``, ``pipeline_ms_*``), so it never competes with
    the replayed backends on speed."""
    return row.recorded_outputs is not None


def with_recorded_latency(
    summaries: Sequence[SummaryRow], records: Sequence[FrameRecord], *, seed: int = 0
) -> list[SummaryRow]:
    """``summaries`` with the recorded-latency fields (``RECORDED_COLUMNS``) set for each
    (backend, topic) that replays recorded outputs, from the frame ``records`` they were
    computed from; the other rows as they are."""
    groups: dict[tuple[str, str], list[FrameRecord]] = {}
    for record in records:
        groups.setdefault((record.backend, record.topic), []).append(record)
    out: list[SummaryRow] = []
    for s in summaries:
        rows = groups.get((s.backend, s.topic), [])
        found = recorded_summary(s.backend, s.topic, rows, seed=seed)
        out.append(s if found is None else replace(s, **found))
    return out
