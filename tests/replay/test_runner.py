from __future__ import annotations

import csv
import itertools
import json
import sys
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagtools import image_msg, noise_frames, write_mcap

from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import DecodeError, SourceError, UsageError
from replaybench.replay import Rate, VirtualClock
from replaybench.replay.runner import RunConfig, default_warmup, run_benchmark
from replaybench.results.io import to_json
from replaybench.results.model import ReadAhead
from replaybench.types import BackendResult, Detection, Frame, StageTimes

NS = 1_000_000_000


class ServiceTimeBackend:
    """A backend of declared service time: it advances the virtual clock and finds one box."""

    name: ClassVar[str] = 'service'
    description: ClassVar[str] = 'declared service time'

    def __init__(self, clock: VirtualClock, service_s: float) -> None:
        self.clock = clock
        self.service_s = service_s
        self.seen: list[int] = []

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        self.clock.advance(self.service_s)
        self.seen.append(frame.seq)
        box = Detection(0, 'thing', 0.5, 1.0, 2.0, 10.0, 12.0)
        return BackendResult((box,), StageTimes(infer_ns=int(self.service_s * 1e9)))

    def info(self) -> dict[str, Any]:
        return {'service_s': self.service_s}

    def close(self) -> None:
        pass


def _rows(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / 'frames.csv').open(newline='') as f:
        return list(csv.DictReader(f))


def _bag(path: Path, n: int = 30, hz: int = 30) -> Path:
    frames = noise_frames(n)
    t0 = 1_700_000_000 * NS
    write_mcap(
        path,
        [
            (
                '/cam/image_raw',
                t0 + i * NS // hz,
                image_msg(t0 + i * NS // hz, frames[i]),
                'sensor_msgs/msg/Image',
            )
            for i in range(n)
        ],
    )
    return path


def test_recorded_rate_with_a_slow_backend_drops_exactly_the_frames_it_should(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=10, hz=10)
    clock = VirtualClock()
    backend = ServiceTimeBackend(clock, service_s=0.27)  # 270 ms per frame, a frame every 100 ms
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['service'],
            out_dir=tmp_path / 'run',
            rate=Rate('recorded'),
            warmup=0,
        ),
        clock=clock,
        backend_factory=lambda name, options: backend,
    )
    assert outcome.run_dir is not None
    rows = _rows(outcome.run_dir)
    assert len(rows) == 10
    # 0 runs 0-0.27 s; 1 waits and is pushed out by 2 (0.2); 2 runs 0.27-0.54 while 3, 4, 5
    # arrive (5 stays); 5 runs 0.54-0.81 while 6, 7, 8 arrive (8 stays); 8 runs 0.81-1.08;
    # 9 waits and runs last.
    dropped = [int(r['seq']) for r in rows if r['status'] == 'dropped']
    assert dropped == [1, 3, 4, 6, 7]
    assert backend.seen == [0, 2, 5, 8, 9]
    assert [r['seq'] for r in rows] == [str(i) for i in range(10)]
    summary = outcome.run.summary_rows[0]
    assert summary.dropped == 5
    assert summary.measured == 5
    waits = {int(r['seq']): float(r['queue_wait_ms']) for r in rows if r['status'] == 'ok'}
    assert waits == pytest.approx({0: 0.0, 2: 70.0, 5: 40.0, 8: 10.0, 9: 180.0}, abs=1e-3)
    latencies = {int(r['seq']): float(r['latency_ms']) for r in rows if r['status'] == 'ok'}
    assert latencies == pytest.approx({0: 270.0, 2: 340.0, 5: 310.0, 8: 280.0, 9: 450.0}, abs=1e-3)


def test_a_fast_backend_at_recorded_rate_drops_nothing_and_latency_is_its_service_time(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=12)
    clock = VirtualClock()
    backend = ServiceTimeBackend(clock, service_s=0.01)
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['service'],
            out_dir=tmp_path / 'run',
            rate=Rate('recorded'),
            warmup=2,
        ),
        clock=clock,
        backend_factory=lambda name, options: backend,
    )
    assert outcome.run_dir is not None
    rows = _rows(outcome.run_dir)
    assert [r['status'] for r in rows] == ['ok'] * 12
    assert [r['warmup'] for r in rows] == ['1', '1'] + ['0'] * 10
    assert {round(float(r['latency_ms']), 6) for r in rows} == {10.0}
    summary = outcome.run.summary_rows[0]
    assert summary.measured == 10
    assert summary.latency_ms_p99 == pytest.approx(10.0)


def test_a_fixed_rate_releases_frames_at_that_rate_whatever_the_log_times(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=10)
    clock = VirtualClock()
    backend = ServiceTimeBackend(clock, service_s=0.001)
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag], backends=['service'], out_dir=tmp_path / 'run', rate=Rate('fixed', hz=5.0)
        ),
        clock=clock,
        backend_factory=lambda name, options: backend,
    )
    assert outcome.run_dir is not None
    releases = [float(r['release_s']) for r in _rows(outcome.run_dir)]
    assert releases == pytest.approx([i / 5 for i in range(10)])


def test_one_undecodable_message_is_skipped_counted_and_kept_in_frames_csv(tmp_path):
    frames = noise_frames(6)
    t0 = 1_700_000_000 * NS
    messages = []
    for i in range(6):
        msg = image_msg(t0 + i * NS // 10, frames[i])
        if i == 3:  # step x height does not match the data
            msg = image_msg(t0 + i * NS // 10, frames[i], data=bytes(100))
        messages.append(('/cam/image_raw', t0 + i * NS // 10, msg, 'sensor_msgs/msg/Image'))
    bag = tmp_path / 'bad.mcap'
    write_mcap(bag, messages)
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run', report=False)
    )
    assert outcome.run_dir is not None
    rows = _rows(outcome.run_dir)
    assert [r['status'] for r in rows] == ['ok', 'ok', 'ok', 'skipped', 'ok', 'ok']
    assert rows[3]['note']
    assert outcome.run.counts is not None
    assert outcome.run.counts.skipped == 1
    assert sum(outcome.run.skipped.values()) == 1


def test_a_bag_where_no_frame_decodes_fails_with_the_reason(tmp_path):
    frames = noise_frames(3)
    bag = tmp_path / 'allbad.mcap'
    write_mcap(
        bag,
        [
            ('/cam/image_raw', i, image_msg(i, frames[i], data=bytes(10)), 'sensor_msgs/msg/Image')
            for i in range(3)
        ],
    )
    # the probe already finds the first message broken; either way the run stops with exit 2
    with pytest.raises((DecodeError, SourceError, UsageError)):
        run_benchmark(
            RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run', report=False)
        )


def test_a_depth_only_bag_names_the_topics_and_runs_when_they_are_selected(tmp_path):
    t0 = 1_700_000_000 * NS
    depth = np.arange(48 * 64, dtype=np.uint16).reshape(48, 64)
    messages = [
        (
            '/cam/depth/image_raw',
            t0 + i,
            image_msg(t0 + i, depth, encoding='16UC1', data=depth.tobytes()),
            'sensor_msgs/msg/Image',
        )
        for i in range(3)
    ]
    for _, _, msg, _ in messages:
        msg.step = 128  # type: ignore[attr-defined]
    bag = tmp_path / 'depth.mcap'
    write_mcap(bag, messages)
    with pytest.raises(UsageError, match='--topic /cam/depth/image_raw'):
        run_benchmark(RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run'))
    assert not (tmp_path / 'run').exists()
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['null'],
            out_dir=tmp_path / 'run',
            topics=['/cam/depth/image_raw'],
            report=False,
        )
    )
    assert outcome.run.counts is not None
    assert outcome.run.counts.processed == 3


def test_a_non_empty_output_folder_is_refused_without_force(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=3)
    out = tmp_path / 'run'
    out.mkdir()
    (out / 'keep.txt').write_text('mine')
    with pytest.raises(UsageError, match='--force'):
        run_benchmark(RunConfig(inputs=[bag], backends=['null'], out_dir=out, report=False))
    # --force replaces a run folder only, and this one holds no run.json
    with pytest.raises(UsageError, match='not a run folder'):
        run_benchmark(
            RunConfig(inputs=[bag], backends=['null'], out_dir=out, force=True, report=False)
        )
    assert [p.name for p in out.iterdir()] == ['keep.txt']
    assert (out / 'keep.txt').read_text() == 'mine'


def test_an_interrupted_run_leaves_valid_finalized_outputs_marked_interrupted(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=20)
    clock = VirtualClock()

    class Interrupting(ServiceTimeBackend):
        def detect(self, frame: Frame) -> BackendResult:
            if frame.seq == 7:
                raise KeyboardInterrupt
            return super().detect(frame)

    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['service'], out_dir=tmp_path / 'run', warmup=0),
        clock=clock,
        backend_factory=lambda name, options: Interrupting(clock, 0.01),
    )
    assert outcome.status == 'interrupted'
    assert outcome.run_dir is not None
    run = json.loads((outcome.run_dir / 'run.json').read_text())
    assert run['status'] == 'interrupted'
    assert len(_rows(outcome.run_dir)) == 7
    from mcap.reader import make_reader

    with (outcome.run_dir / 'outputs.mcap').open('rb') as f:
        messages = list(make_reader(f).iter_messages())
    assert len([m for m in messages if m[1].topic.startswith('/replaybench/')]) == 7
    assert not list(outcome.run_dir.glob('*.part'))


def test_max_frames_start_and_duration_restrict_the_replay(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=30)
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag], backends=['null'], out_dir=tmp_path / 'a', max_frames=5, report=False
        )
    )
    assert outcome.run_dir is not None
    assert [int(r['seq']) for r in _rows(outcome.run_dir)] == [0, 1, 2, 3, 4]
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['null'],
            out_dir=tmp_path / 'b',
            start_s=0.5,
            duration_s=0.2,
            report=False,
        )
    )
    assert outcome.run_dir is not None
    seqs = [int(r['seq']) for r in _rows(outcome.run_dir)]
    assert seqs == [15, 16, 17, 18, 19, 20]  # log times 0.5 s <= t < 0.7 s after the first message


def test_several_bags_are_separate_inputs_of_one_run(tmp_path):
    a = _bag(tmp_path / 'a.mcap', n=4)
    b = _bag(tmp_path / 'b.mcap', n=3)
    outcome = run_benchmark(
        RunConfig(inputs=[a, b], backends=['null'], out_dir=tmp_path / 'run', report=False)
    )
    assert outcome.run_dir is not None
    rows = _rows(outcome.run_dir)
    assert [(r['input'], r['seq']) for r in rows] == [
        ('0', '0'),
        ('0', '1'),
        ('0', '2'),
        ('0', '3'),
        ('1', '0'),
        ('1', '1'),
        ('1', '2'),
    ]
    assert [i.path for i in outcome.run.inputs] == [str(a), str(b)]
    assert all(len(i.sha256 or '') == 64 for i in outcome.run.inputs)


@pytest.mark.parametrize(
    ('frames', 'warmup'), [(0, 0), (3, 0), (9, 0), (10, 1), (55, 5), (100, 10), (5000, 10)]
)
def test_the_default_warmup_never_swallows_a_short_bag(frames, warmup):
    assert default_warmup(frames) == warmup


def test_backend_options_reach_the_backend(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=2)
    seen: list[BackendOptions] = []

    def factory(_name: str, options: BackendOptions) -> ServiceTimeBackend:
        seen.append(options)
        return ServiceTimeBackend(VirtualClock(), 0.0)

    run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['service'],
            out_dir=tmp_path / 'run',
            threads=1,
            options=BackendOptions(threads=1),
            report=False,
        ),
        backend_factory=factory,
    )
    assert seen[0].threads == 1


class SteppingClock:
    """A clock that moves ``step`` seconds every time it is read: reading a frame takes as
    long as the number of readings around it says, whatever the machine."""

    def __init__(self, step: float) -> None:
        self.step = step
        self.t = 0.0

    def now(self) -> float:
        self.t += self.step
        return self.t

    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)


def _max_rate_run(tmp_path: Path, name: str, clock: SteppingClock, **config: Any) -> Any:
    return run_benchmark(
        RunConfig(
            inputs=[_bag(tmp_path / 'cam.mcap', n=40)],
            backends=['hsv'],
            out_dir=tmp_path / name,
            force=True,
            report=False,
            **config,
        ),
        clock=clock,
    )


def _detections_by_frame(run_dir: Path) -> list[tuple[str, str, str]]:
    return [(r['seq'], r['status'], r['detections']) for r in _rows(run_dir)]


def test_at_max_rate_frames_cheap_to_read_are_read_inline_and_run_json_says_why(tmp_path):
    outcome = _max_rate_run(tmp_path, 'fast', SteppingClock(1e-6))
    (decision,) = outcome.run.backends[0].read_ahead
    assert decision.used is False
    assert decision.probe_frames == 15
    assert decision.probe_read_decode_ms is not None
    assert decision.threshold_ms is not None
    assert decision.probe_read_decode_ms < decision.threshold_ms


def test_at_max_rate_frames_slow_to_read_are_read_ahead_with_the_same_results(tmp_path):
    slow = _max_rate_run(tmp_path, 'slow', SteppingClock(1e-3))
    (decision,) = slow.run.backends[0].read_ahead
    assert to_json(decision) == {
        'input': 0,
        'depth': 4,
        'used': True,
        'probe_frames': 15,
        # a frame is released when the previous one is done: one clock reading until its detect
        'probe_read_decode_ms': pytest.approx(1.0),
        'threshold_ms': pytest.approx(0.2),
    }
    fast = _max_rate_run(tmp_path, 'fast', SteppingClock(1e-6))
    serial = _max_rate_run(tmp_path, 'serial', SteppingClock(1e-3), prefetch=0)
    assert serial.run.backends[0].read_ahead == (
        ReadAhead(input=0, depth=0, used=False, reason='prefetch=0'),
    )
    expected = _detections_by_frame(serial.run_dir)
    assert len(expected) == 40
    assert _detections_by_frame(slow.run_dir) == expected
    assert _detections_by_frame(fast.run_dir) == expected


def test_a_bag_shorter_than_the_probe_is_read_inline(tmp_path):
    outcome = run_benchmark(
        RunConfig(
            inputs=[_bag(tmp_path / 'cam.mcap', n=5)],
            backends=['null'],
            out_dir=tmp_path / 'run',
            report=False,
        ),
        clock=SteppingClock(1e-3),
    )
    assert outcome.run.backends[0].read_ahead == (
        ReadAhead(input=0, depth=4, used=False, reason='input ended in the probe'),
    )
    assert outcome.run_dir is not None
    assert len(_rows(outcome.run_dir)) == 5


def test_inline_a_frame_is_released_the_moment_the_previous_one_is_done(tmp_path):
    # prefetch=0: every frame read inline; the stepping clock moves 1 ms a reading
    outcome = _max_rate_run(tmp_path, 'run', SteppingClock(1e-3), prefetch=0, warmup=0)
    rows = _rows(outcome.run_dir)
    assert len(rows) == 40
    for previous, row in itertools.pairwise(rows):
        assert row['release_s'] == previous['done_s']
    # what latency includes: reading + decoding (one reading: the frame is decoded by the
    # time the clock is read before detect) and the backend (one reading after detect)
    assert {row['read_decode_ms'] for row in rows} == {'1.0000'}
    assert {row['latency_ms'] for row in rows} == {'2.0000'}
    assert {row['queue_wait_ms'] for row in rows} == {'0.0000'}


def test_progress_is_reported_in_order_up_to_the_total(tmp_path):
    seen: list[tuple[int, int]] = []
    run_benchmark(
        RunConfig(
            inputs=[_bag(tmp_path / 'cam.mcap', n=150)],
            backends=['null', 'hsv'],
            out_dir=tmp_path / 'run',
            report=False,
        ),
        progress=lambda done, total: seen.append((done, total)),
    )
    assert seen[-1] == (300, 300)
    assert [done for done, _ in seen] == sorted(done for done, _ in seen)
    # at max rate in batches, not once a frame
    assert len(seen) < 20


def test_the_sample_is_the_middle_frame_read_again_with_every_backends_boxes(tmp_path):
    from replaybench.app.run import run_benchmark as run_with_report
    from replaybench.decode import decode_image, to_bgr8
    from replaybench.report import write_sample
    from replaybench.sources import open_source

    bag = _bag(tmp_path / 'cam.mcap', n=9)
    clock = VirtualClock()
    outcome = run_with_report(
        RunConfig(inputs=[bag], backends=['service', 'null'], out_dir=tmp_path / 'run'),
        clock=clock,
        backend_factory=lambda name, options: (
            ServiceTimeBackend(clock, 0.01) if name == 'service' else _null(options)
        ),
    )
    assert outcome.run.outputs is not None
    assert outcome.run.outputs.samples == ('samples/input0_cam_image_raw.jpg',)
    with open_source(bag) as source:
        middle = next(m for m in source.messages() if m.seq == 4)
        frame = decode_image(middle)
        box = Detection(0, 'thing', 0.5, 1.0, 2.0, 10.0, 12.0)
        write_sample(
            tmp_path / 'expected.jpg',
            to_bgr8(frame.image, frame.encoding),
            {'service': (box,), 'null': ()},
            '/cam/image_raw #4',
        )
    assert outcome.run_dir is not None
    written = (outcome.run_dir / 'samples' / 'input0_cam_image_raw.jpg').read_bytes()
    assert written == (tmp_path / 'expected.jpg').read_bytes()


def _null(options: BackendOptions) -> Any:
    from replaybench.backends.null import NullBackend

    return NullBackend(options)


def test_progress_of_a_slow_backend_is_reported_every_quarter_second_or_so(tmp_path):
    seen: list[int] = []
    run_benchmark(
        RunConfig(
            inputs=[_bag(tmp_path / 'cam.mcap', n=10)],
            backends=['null'],
            out_dir=tmp_path / 'run',
            report=False,
            prefetch=0,
        ),
        clock=SteppingClock(0.1),  # 0.2 s a frame: read + decode, then detect
        progress=lambda done, total: seen.append(done),
    )
    assert seen == [2, 4, 6, 8, 10]
