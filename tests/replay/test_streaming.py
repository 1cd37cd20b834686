"""Streaming scores: each frame's truth against the output in use at its release, on the
virtual clock (exact times). A test backend returns each frame's truth boxes after a set delay
on a fixture whose one object stands still and whose other moves 12 px a frame; the expected
figures are counted here from the boxes and the frames' times, independently of the engine."""

from __future__ import annotations

import csv
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pytest

from replaybench.backends.base import Availability
from replaybench.fixtures.writer import GROUND_TRUTH_TOPIC, FixtureMessage, write_ros2_mcap
from replaybench.msgs import DETECTION2DARRAY, IMAGE, serialize_detections, serialize_image
from replaybench.replay import Rate, VirtualClock
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.replay.streaming import REFUSED_AT_MAX, StreamFrame, pick_outputs
from replaybench.results.accuracy import evaluate
from replaybench.types import BackendResult, Detection, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    from replaybench.replay.runner import RunOutcome
    from replaybench.types import Frame

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
FRAMES = 24
TOPIC = '/cam/image_raw'
#: the moving object's speed (px per frame) and width: one frame's shift leaves IoU 8/32
SPEED, WIDTH = 12, 20


def _stamp(i: int) -> int:
    return T0 + i * NS // 30


def _truth(i: int) -> tuple[Detection, ...]:
    moving = 4 + SPEED * i
    return (
        Detection(0, 'still', 1.0, 10.0, 10.0, 30.0, 30.0),
        Detection(1, 'moving', 1.0, float(moving), 40.0, float(moving + WIDTH), 60.0),
    )


def _bag(path: Path) -> Path:
    image = np.zeros((80, 320, 3), np.uint8)
    messages: list[FixtureMessage] = []
    for i in range(FRAMES):
        stamp = _stamp(i)
        messages.append(
            FixtureMessage(stamp, TOPIC, IMAGE, serialize_image(stamp, 'cam', image, 'rgb8'))
        )
        messages.append(
            FixtureMessage(
                stamp,
                GROUND_TRUTH_TOPIC,
                DETECTION2DARRAY,
                serialize_detections(stamp, 'cam', _truth(i)),
            )
        )
    return write_ros2_mcap(path, messages)


class DelayedTruth:
    """Returns the frame's truth boxes after ``delay_s`` on the virtual clock."""

    name: ClassVar[str] = 'oracle'
    description: ClassVar[str] = 'truth boxes after a delay'

    def __init__(self, clock: VirtualClock, delay_s: float) -> None:
        self.clock = clock
        self.delay_s = delay_s
        self.index = {_stamp(i): i for i in range(FRAMES)}

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        self.clock.advance(self.delay_s)
        return BackendResult(
            _truth(self.index[frame.stamp_ns]), StageTimes(infer_ns=round(self.delay_s * 1e9))
        )

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


def _run(
    tmp_path: Path, delay_s: float, rate: Rate | None = None, added_ms: float | None = None
) -> RunOutcome:
    clock = VirtualClock()
    name = f'd{delay_s * 1e3:g}-a{added_ms}-{rate or "30hz"}'
    return run_benchmark(
        RunConfig(
            inputs=[_bag(tmp_path / f'{name}.mcap')],
            backends=['oracle'],
            out_dir=tmp_path / name,
            rate=rate or Rate('fixed', hz=30.0),
            warmup=0,
            report=False,
            added_latency_ms=added_ms,
        ),
        clock=clock,
        backend_factory=lambda _name, _options: DelayedTruth(clock, delay_s),
    )


def _frames(outcome: RunOutcome) -> list[dict[str, str]]:
    assert outcome.run_dir is not None
    with (outcome.run_dir / 'frames.csv').open(newline='') as f:
        return list(csv.DictReader(f))


def _iou(a: Detection, b: Detection) -> float:
    w = max(0.0, min(a.x1, b.x1) - max(a.x0, b.x0))
    h = max(0.0, min(a.y1, b.y1) - max(a.y0, b.y0))
    inter = w * h
    union = (a.x1 - a.x0) * (a.y1 - a.y0) + (b.x1 - b.x0) * (b.y1 - b.y0) - inter
    return inter / union


def _expected(shown: Mapping[int, int | None]) -> dict[str, float]:
    """Recall, precision and mAP@0.5 of truth frame i scored against frame shown[i]'s truth
    boxes (no boxes for None), counted box by box; mAP from the offline scorer given the
    shifted boxes directly."""
    tp = n_det = 0
    n_gt = 2 * len(shown)
    for i, j in shown.items():
        if j is None:
            continue
        for truth, det in zip(_truth(i), _truth(j), strict=True):
            n_det += 1
            tp += _iou(truth, det) >= 0.5
    direct = evaluate(
        {i: _truth(i) for i in shown},
        {i: () if j is None else _truth(j) for i, j in shown.items()},
    )
    return {'recall': tp / n_gt, 'precision': tp / n_det, 'map50': direct.map50}


def _streaming(outcome: RunOutcome) -> Mapping[str, float | None]:
    [row] = outcome.summaries
    assert row.task_metrics is not None
    return row.task_metrics


def test_one_frame_of_delay_loses_the_moving_object_and_the_first_frame_as_counted(
    tmp_path: Path,
) -> None:
    outcome = _run(tmp_path, 0.020)
    frames = _frames(outcome)
    # 20 ms of latency at 30 Hz: each frame scored against the previous frame's output
    assert [f['output_age_ms'] for f in frames] == ['', *['33.3333'] * (FRAMES - 1)]
    expected = _expected({i: i - 1 if i else None for i in range(FRAMES)})
    # the still object is matched from frame 1 on, the moving one (IoU 0.25) never
    assert expected['recall'] == pytest.approx((FRAMES - 1) / (2 * FRAMES))
    assert expected['precision'] == pytest.approx(0.5)
    found = _streaming(outcome)
    assert found['streaming_recall'] == pytest.approx(expected['recall'])
    assert found['streaming_precision'] == pytest.approx(expected['precision'])
    assert found['streaming_map50'] == pytest.approx(expected['map50'])
    [row] = outcome.summaries
    assert row.map50 == pytest.approx(1.0)  # offline: every output against its own frame
    assert row.map50 is not None
    assert (found['streaming_map50'] or 1.0) < row.map50 - 0.4


def test_with_zero_delay_the_streaming_scores_equal_the_offline_ones(tmp_path: Path) -> None:
    outcome = _run(tmp_path, 0.0)
    assert [f['output_age_ms'] for f in _frames(outcome)] == ['0.0000'] * FRAMES
    found = _streaming(outcome)
    [row] = outcome.summaries
    assert row.map50 is not None
    assert found['streaming_map50'] == row.map50
    assert found['streaming_map50_95'] == row.map50_95
    assert found['streaming_recall'] == row.recall50
    assert found['streaming_precision'] == row.precision50


def test_with_drops_each_dropped_frame_is_scored_against_the_output_in_use_before_it(
    tmp_path: Path,
) -> None:
    outcome = _run(tmp_path, 0.045)  # 45 ms a frame at 30 Hz, queue depth 1: frames drop
    frames = _frames(outcome)
    dropped = [int(f['seq']) for f in frames if f['dropped'] == '1']
    assert dropped
    # the output in use at each frame's release, from frames.csv's times alone
    done = [(float(f['done_s']), int(f['seq'])) for f in frames if f['status'] == 'ok']
    shown: dict[int, int | None] = {}
    for f in frames:
        released = float(f['release_s'])
        finished = [(t, seq) for t, seq in done if t <= released]
        shown[int(f['seq'])] = max(finished)[1] if finished else None
    assert all((shown[i] or i) < i for i in dropped if i > 1)
    for f in frames:
        i = int(f['seq'])
        j = shown[i]
        age = '' if j is None else f'{(_stamp(i) - _stamp(j)) / 1e6:.4f}'
        assert f['output_age_ms'] == age, i
    expected = _expected(shown)
    found = _streaming(outcome)
    assert found['streaming_recall'] == pytest.approx(expected['recall'])
    assert found['streaming_precision'] == pytest.approx(expected['precision'])
    assert found['streaming_map50'] == pytest.approx(expected['map50'])


def test_at_max_rate_the_streaming_scores_are_refused_with_the_reason(tmp_path: Path) -> None:
    outcome = _run(tmp_path, 0.020, Rate('max'))
    found = _streaming(outcome)
    assert set(found) == {
        'streaming_map50',
        'streaming_map50_95',
        'streaming_recall',
        'streaming_precision',
    }
    assert all(v is None for v in found.values())
    assert REFUSED_AT_MAX in outcome.run.warnings
    assert {f['output_age_ms'] for f in _frames(outcome)} == {''}
    assert outcome.run_dir is not None
    with (outcome.run_dir / 'summary.csv').open(newline='') as f:
        [row] = list(csv.DictReader(f))
    assert row['streaming_map50'] == ''


def _picks(frames: Sequence[tuple[float, float | None]]) -> list[int | None]:
    found = pick_outputs(
        0, [StreamFrame(('/t', i, i, i, ''), r, a) for i, (r, a) in enumerate(frames)]
    )
    return [None if p.output is None else p.output[1] for p in found]


def test_the_output_picked_is_the_latest_finished_at_the_release_whichever_frame_it_came_from() -> (
    None
):
    # frame 1 finishes after frame 2 (two workers): at 0.3 frame 2's output is the latest
    assert _picks([(0.0, 0.25), (0.1, 0.35), (0.2, 0.28), (0.3, None), (0.4, None)]) == [
        None,
        None,
        None,
        2,
        1,
    ]
    # an output finished exactly at a release is in use there
    assert _picks([(0.0, 0.1), (0.1, 0.2)]) == [None, 0]


def test_added_latency_is_a_wait_inside_detect_counted_in_the_latency_and_the_streaming_scores(
    tmp_path: Path,
) -> None:
    added = _run(tmp_path, 0.0, added_ms=20.0)
    frames = _frames(added)
    assert {f['latency_ms'] for f in frames} == {'20.0000'}
    assert {f['infer_ms'] for f in frames} == {'0.0000'}  # the backend's own stage, as it said
    assert [f['output_age_ms'] for f in frames] == ['', *['33.3333'] * (FRAMES - 1)]
    delayed = _run(tmp_path, 0.020)
    assert _streaming(added) == _streaming(delayed)
    assert added.run.settings.added_latency_ms == 20.0
    assert delayed.run.settings.added_latency_ms is None


def test_the_report_shows_offline_against_streaming_and_the_output_ages(tmp_path: Path) -> None:
    from replaybench.report import render_report

    outcome = _run(tmp_path, 0.020)
    assert outcome.run_dir is not None
    page = render_report(outcome.run_dir).read_text(encoding='utf-8')
    section = page[page.index('<h2 id="streaming">') :]
    found = _streaming(outcome)['streaming_map50']
    assert found is not None
    assert f'<td class="n">1.000</td><td class="n">{found:.3f}</td>' in section
    assert f'{found - 1:+.3f}' in section
    # the distribution: 23 frames 33 ms old, the first without an output
    assert '<td class="n">33 ms</td><td class="n">23</td>' in section
    assert '<td class="n">no output yet</td><td class="n">1</td>' in section
    # a run without streaming scores has no such section
    refused = _run(tmp_path, 0.020, Rate('max'))
    assert refused.run_dir is not None
    assert 'id="streaming"' not in render_report(refused.run_dir).read_text(encoding='utf-8')


def test_a_frame_header_is_read_without_its_pixels_as_the_decoder_reads_it(tmp_path: Path) -> None:
    from pathlib import Path

    from replaybench.decode.image import decode_image, image_header
    from replaybench.sources import open_source

    root = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags'
    for bag in (_bag(tmp_path / 'h.mcap'), root / 'jpeg.mcap', root / 'rgb8.bag'):
        with open_source(bag) as source:
            images = [t.name for t in source.topics() if 'Image' in t.msgtype]
            for raw in source.messages(topics=images):
                frame = decode_image(raw)
                assert image_header(raw) == (frame.stamp_ns, frame.frame_id)
