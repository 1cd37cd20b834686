"""Streaming scores of tracks: the tracks recorded live in live_tracks.mcap, each image frame
scored against the recorded tracks that were the latest logged at its log time (picked here,
from the bag alone), the frames one sequence scored as offline tracks are."""

from __future__ import annotations

import bisect
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

import replaybench as rb
from replaybench.decode import decode_detections, decode_image
from replaybench.fixtures.live import LIVE_TRACKS_TOPIC
from replaybench.sources import open_source
from replaybench.tasks.tracks.recording import figures_of, score_sequence

if TYPE_CHECKING:
    from replaybench.types import Detection

BAG = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'live_tracks.mcap'
TRUTH = '/ground_truth/detections'


def _expected() -> dict[str, float | None]:
    images: list[tuple[int, int]] = []  # (log time, stamp)
    outputs: list[tuple[int, tuple[Detection, ...]]] = []
    truth: dict[int, tuple[Detection, ...]] = {}
    with open_source(BAG) as source:
        for raw in source.messages():
            if raw.topic == LIVE_TRACKS_TOPIC:
                outputs.append((raw.log_time_ns, decode_detections(raw).detections))
            elif raw.topic == TRUTH:
                found = decode_detections(raw)
                truth[found.stamp_ns] = found.detections
            elif raw.msgtype.endswith('CompressedImage'):
                images.append((raw.log_time_ns, decode_image(raw).stamp_ns))
    outputs.sort(key=lambda o: o[0])
    times = [t for t, _ in outputs]
    frames = []
    for log_time, stamp in images:
        n = bisect.bisect_right(times, log_time)  # the latest logged at or before the frame
        shown = outputs[n - 1][1] if n else ()
        frames.append((truth[stamp], shown))
    return figures_of(score_sequence(frames))


def test_recorded_tracks_are_scored_against_the_tracks_logged_before_each_frame(
    tmp_path: Path,
) -> None:
    result = rb.run(BAG, backends=['recorded'], out=tmp_path / 'run', report=False)
    (row,) = result.summary_rows
    expected = _expected()
    assert row.metric('streaming_hota') == pytest.approx(expected['hota'], abs=1e-12)
    assert row.metric('streaming_idf1') == pytest.approx(expected['idf1'], abs=1e-12)
    assert row.metric('streaming_mota') == pytest.approx(expected['mota'], abs=1e-12)
    idf1 = row.metric('idf1')
    assert idf1 is not None
    assert expected['idf1'] is not None
    assert expected['idf1'] < idf1  # the node's tracks come 44 ms late: a frame later
