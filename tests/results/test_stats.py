"""Summary statistics against values worked out by hand."""

from __future__ import annotations

import math
import random
from dataclasses import asdict, replace

import pytest

from replaybench.results.model import Accuracy, SummaryRow
from replaybench.results.records import FrameRecord
from replaybench.results.stats import SUMMARY_CSV_COLUMNS, summarize, summary_json, summary_row


def _ok(
    seq: int,
    latency: float,
    start: float,
    done: float,
    *,
    warmup: bool = False,
    backend: str = 'hsv',
    topic: str = '/cam',
    detections: int = 1,
    infer: float | None = None,
) -> FrameRecord:
    return FrameRecord(
        0, backend, topic, seq, seq, seq, 'ok', '', warmup, False, start, start, done,
        0.0, 0.5, None, infer, None, None, None, latency, detections,
    )  # fmt: skip


def _dropped(seq: int, release: float, backend: str = 'hsv', topic: str = '/cam') -> FrameRecord:
    return FrameRecord(0, backend, topic, seq, seq, None, 'dropped', 'queue', False, True, release)


def _skipped(seq: int, release: float) -> FrameRecord:
    return FrameRecord(0, 'hsv', '/cam', seq, seq, None, 'skipped', 'bad', False, False, release)


def _records() -> list[FrameRecord]:
    # Two warm-up frames with huge latencies, five measured ones, one dropped, one skipped.
    return [
        _ok(0, 500.0, 0.0, 0.5, warmup=True, detections=9),
        _ok(1, 600.0, 0.5, 1.0, warmup=True, detections=9),
        _ok(2, 10.0, 1.1, 1.4, detections=1, infer=2.0),
        _dropped(3, 1.2),
        _ok(4, 20.0, 1.4, 1.8, detections=2, infer=4.0),
        _skipped(5, 1.9),
        _ok(6, 30.0, 1.8, 2.2, detections=3),
        _ok(7, 40.0, 2.2, 2.6, detections=4),
        _ok(8, 100.0, 2.6, 3.0, detections=0),
    ]


def test_counts_separate_measured_warmup_dropped_and_skipped() -> None:
    [s] = summarize(_records())
    assert (s.backend, s.topic) == ('hsv', '/cam')
    assert s.frames == 9
    assert s.processed == 7
    assert s.measured == 5
    assert s.warmup == 2
    assert s.dropped == 1
    assert s.skipped == 1


def test_latency_statistics_use_measured_frames_only() -> None:
    [s] = summarize(_records())
    # measured latencies: 10, 20, 30, 40, 100
    assert s.latency_ms_mean == pytest.approx(40.0)
    assert s.latency_ms_std == pytest.approx(math.sqrt(1000.0))  # population std
    assert s.latency_ms_min == 10.0
    assert s.latency_ms_max == 100.0
    assert s.latency_ms_p50 == pytest.approx(30.0)
    # linear interpolation at rank q/100 * (n - 1)
    assert s.latency_ms_p90 == pytest.approx(40.0 + 0.6 * 60.0)
    assert s.latency_ms_p95 == pytest.approx(40.0 + 0.8 * 60.0)
    assert s.latency_ms_p99 == pytest.approx(40.0 + 0.96 * 60.0)


def test_jitter_is_the_mean_absolute_step_between_consecutive_latencies() -> None:
    [s] = summarize(_records())
    assert s.jitter_ms == pytest.approx((10 + 10 + 10 + 60) / 4)


def test_jitter_follows_replay_order_not_record_order() -> None:
    records = _records()
    shuffled = records[:]
    random.Random(3).shuffle(shuffled)
    assert summarize(shuffled)[0].jitter_ms == pytest.approx(22.5)


def test_throughput_window_starts_where_warm_up_ends() -> None:
    [s] = summarize(_records())
    # window: done_s of the last warm-up frame (1.0) to done_s of the last measured frame (3.0),
    # not from the first measured frame's start (1.1)
    assert s.throughput_fps == pytest.approx(5 / 2.0)


def test_throughput_without_warm_up_starts_at_the_first_start() -> None:
    records = [r._replace(warmup=False) for r in _records() if r.seq >= 2]
    [s] = summarize(records)
    # first measured frame starts at 1.1, last one is done at 3.0
    assert s.throughput_fps == pytest.approx(5 / 1.9)
    assert s.warmup == 0


def test_throughput_is_none_for_a_zero_window() -> None:
    [s] = summarize([_ok(0, 1.0, 1.0, 1.0)])
    assert s.throughput_fps is None
    assert s.jitter_ms is None
    assert s.latency_ms_p99 == 1.0


def test_detections_and_stage_means_cover_measured_frames() -> None:
    [s] = summarize(_records())
    assert s.detections_per_frame == pytest.approx((1 + 2 + 3 + 4 + 0) / 5)
    assert s.infer_ms_mean == pytest.approx(3.0)  # only frames that have the stage
    assert s.read_decode_ms_mean == pytest.approx(0.5)
    assert s.queue_wait_ms_mean == pytest.approx(0.0)
    assert s.preprocess_ms_mean is None
    assert s.h2d_ms_mean is None


def test_a_group_without_measured_frames_has_no_statistics() -> None:
    [s] = summarize([_dropped(0, 0.0), _ok(1, 5.0, 0.0, 0.1, warmup=True)])
    assert (s.frames, s.processed, s.measured, s.dropped) == (2, 1, 0, 1)
    assert s.latency_ms_mean is None
    assert s.latency_ms_p50 is None
    assert s.throughput_fps is None
    assert s.detections_per_frame is None


def test_groups_follow_first_appearance_of_backend_then_topic() -> None:
    records = [
        _ok(0, 1.0, 0.0, 0.1, backend='zeta', topic='/b'),
        _ok(0, 1.0, 0.0, 0.1, backend='alpha', topic='/a'),
        _ok(0, 1.0, 0.0, 0.1, backend='zeta', topic='/a'),
        _ok(0, 1.0, 0.0, 0.1, backend='alpha', topic='/b'),
    ]
    keys = [(s.backend, s.topic) for s in summarize(records)]
    assert keys == [('zeta', '/b'), ('zeta', '/a'), ('alpha', '/b'), ('alpha', '/a')]


def test_summary_row_flattens_accuracy() -> None:
    [s] = summarize(_records())
    row = summary_row(s)
    assert tuple(row) == SUMMARY_CSV_COLUMNS
    assert row['map50'] is None
    assert 'accuracy' not in row
    accuracy = Accuracy(precision50=0.5, recall50=0.25, map50=0.4, map50_95=0.2, ap50={})
    scored = replace(s, accuracy=accuracy, precision50=0.5, recall50=0.25, map50=0.4, map50_95=0.2)
    with_acc = summary_row(scored)
    assert (with_acc['precision50'], with_acc['map50_95']) == (0.5, 0.2)
    assert 'ap50' not in with_acc
    full = summary_json(scored)
    assert full['accuracy'] == {**asdict(accuracy), 'ap50': {}}
    assert full['accuracy']['map50'] == 0.4
    assert full['latency_ms_p50'] == s.latency_ms_p50


def test_a_summary_is_the_summary_row_of_run_json() -> None:
    [s] = summarize(_records())
    assert isinstance(s, SummaryRow)
    assert tuple(summary_row(s)) == SUMMARY_CSV_COLUMNS
