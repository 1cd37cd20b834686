"""``--pipelines per-topic`` on a real rig bag (``replaybench.fixtures.rig``), on a virtual clock.

The calibrated case: a backend that waits 20 ms per frame without using the CPU, four cameras
at 30 Hz. Shared, one instance serves at most 50 of the 120 frames a second (drops of at least
55 %); per-topic, one instance per camera serves every frame (drops of at most 1 %). On a
``ThreadVirtualClock`` each pipeline's worker has its own time line: the figures are exact,
whatever the threads' interleaving.
"""

from __future__ import annotations

import csv
import json
import threading
from collections import Counter
from typing import TYPE_CHECKING, Any, ClassVar

import pytest

from replaybench.backends.base import Availability, BackendOptions
from replaybench.fixtures.rig import LATE_FRAMES, rig_topics, write_rig_mcap
from replaybench.replay import Rate, ThreadVirtualClock
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.types import BackendResult, Frame, StageTimes

if TYPE_CHECKING:
    from pathlib import Path

FRAMES = 90  # 3 s at 30 Hz
SERVICE_S = 0.020
CAMERAS = [image for image, _, _ in rig_topics(4)]


class Waiting:
    """Waits ``SERVICE_S`` per frame on the virtual clock (no CPU), notes what it saw."""

    name: ClassVar[str] = 'waiting'
    description: ClassVar[str] = 'waits 20 ms a frame'
    made: ClassVar[list[Waiting]] = []

    def __init__(self, clock: ThreadVirtualClock, fail_on: tuple[str, int] | None = None) -> None:
        self.clock = clock
        self.fail_on = fail_on
        self.topics: Counter[str] = Counter()
        self.threads: set[int] = set()
        self.opened = self.closed = False

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        self.opened = True

    def detect(self, frame: Frame) -> BackendResult:
        if self.fail_on == (frame.topic, frame.seq):
            msg = 'the detector broke'
            raise RuntimeError(msg)
        self.clock.advance(SERVICE_S)
        self.topics[frame.topic] += 1
        self.threads.add(threading.get_ident())
        return BackendResult((), StageTimes(infer_ns=int(SERVICE_S * 1e9)))

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        self.closed = True


@pytest.fixture(scope='module')
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_rig_mcap(tmp_path_factory.mktemp('rig') / 'rig.mcap', FRAMES, (64, 48), 4)


def _run(
    bag: Path,
    out: Path | None,
    pipelines: str,
    rate: Rate,
    made: list[Waiting],
    *,
    fail_on: tuple[str, int] | None = None,
    backends: tuple[str, ...] = ('waiting',),
    threads: int | None = None,
) -> Any:
    clock = ThreadVirtualClock()

    def factory(name: str, _options: BackendOptions) -> Waiting:
        backend = Waiting(clock, fail_on if name == 'waiting' else None)
        made.append(backend)
        return backend

    config = RunConfig(
        inputs=[bag],
        backends=list(backends),
        out_dir=out,
        rate=rate,
        pipelines=pipelines,
        threads=threads,
        report=False,
        hash_inputs=False,
    )
    return run_benchmark(config, clock=clock, backend_factory=factory)


def _drop_rate(outcome: Any) -> float:
    records = outcome.records
    return float(sum(r.dropped for r in records) / len(records))


def test_one_shared_instance_of_20_ms_drops_at_least_55_percent_of_four_cameras_at_30_hz(
    rig: Path,
) -> None:
    made: list[Waiting] = []
    outcome = _run(rig, None, 'shared', Rate('recorded'), made)
    assert len(made) == 1
    assert len(outcome.records) == 4 * FRAMES - LATE_FRAMES
    served = sum(not r.dropped for r in outcome.records)
    # 50 a second over the 3 s the frames arrive in, and the last one in each camera's queue
    assert served <= 50 * FRAMES / 30 + 4
    assert _drop_rate(outcome) >= 0.55
    assert outcome.run.settings.pipelines is None


@pytest.mark.parametrize('rate', [Rate('recorded'), Rate('fixed', hz=30.0), Rate('recorded', 0.5)])
def test_one_instance_per_camera_serves_every_frame_of_four_cameras(rig: Path, rate: Rate) -> None:
    made: list[Waiting] = []
    outcome = _run(rig, None, 'per-topic', rate, made, threads=1)
    assert len(outcome.records) == 4 * FRAMES - LATE_FRAMES
    assert _drop_rate(outcome) <= 0.01
    # each instance saw one camera only, in a thread of its own, and was opened and closed
    assert sorted(next(iter(b.topics)) for b in made) == sorted(CAMERAS)
    assert all(len(b.topics) == 1 and b.opened and b.closed for b in made)
    assert len({t for b in made for t in b.threads}) == 4
    # each frame released at its own time, served at once: latency is the service time
    ok = [r for r in outcome.records if r.status == 'ok']
    assert all(r.queue_wait_ms == pytest.approx(0.0, abs=1e-9) for r in ok)
    assert all(r.latency_ms == pytest.approx(SERVICE_S * 1e3) for r in ok)
    pipelines = outcome.run.settings.pipelines
    assert (pipelines.mode, pipelines.pipelines, pipelines.threads_per_pipeline) == (
        'per-topic',
        4,
        1,
    )
    assert pipelines.cores >= 1


def test_the_late_camera_frames_are_released_at_their_own_log_times(rig: Path) -> None:
    outcome = _run(rig, None, 'per-topic', Rate('recorded'), [])
    late = [r for r in outcome.records if r.topic == CAMERAS[3]]
    assert [round(r.release_s * 30) for r in late] == list(range(LATE_FRAMES, FRAMES))
    first = [r for r in outcome.records if r.topic == CAMERAS[0]]
    assert [round(r.release_s * 30) for r in first] == list(range(FRAMES))


def test_at_max_each_camera_goes_as_fast_as_its_own_pipeline(rig: Path) -> None:
    shared = _run(rig, None, 'shared', Rate('max'), [])
    per_topic = _run(rig, None, 'per-topic', Rate('max'), [])
    for outcome in (shared, per_topic):
        assert not any(r.dropped for r in outcome.records)
    # per camera: one frame every 20 ms, against one every 80 ms when four share one instance
    for cam in CAMERAS[:3]:
        starts = [r.start_s for r in per_topic.records if r.topic == cam]
        assert starts == pytest.approx([i * SERVICE_S for i in range(FRAMES)])
    span = max(r.done_s for r in shared.records) / max(r.done_s for r in per_topic.records)
    assert span == pytest.approx((4 * FRAMES - LATE_FRAMES) / FRAMES)


def test_per_topic_outputs_are_the_same_bytes_on_every_run(rig: Path, tmp_path: Path) -> None:
    for name in ('a', 'b'):
        _run(rig, tmp_path / name, 'per-topic', Rate('recorded'), [])
    for file in ('frames.csv', 'outputs.mcap'):  # summary.csv holds the real CPU and memory
        assert (tmp_path / 'a' / file).read_bytes() == (tmp_path / 'b' / file).read_bytes()
    with (tmp_path / 'a' / 'frames.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    # the bag's order: the frames of one instant together, each camera's in its own order
    assert [(r['topic'], int(r['seq'])) for r in rows[:4]] == [(c, 0) for c in CAMERAS[:3]] + [
        (CAMERAS[0], 1)
    ]
    run = json.loads((tmp_path / 'a' / 'run.json').read_text())
    assert run['settings']['pipelines']['pipelines'] == 4


def test_a_pipeline_whose_detector_raises_stops_its_backend_and_the_others_finish(
    rig: Path,
) -> None:
    made: list[Waiting] = []
    outcome = _run(
        rig,
        None,
        'per-topic',
        Rate('recorded'),
        made,
        fail_on=(CAMERAS[1], 30),
        backends=('waiting', 'other'),
    )
    assert outcome.status == 'partial'
    (failed,) = [b for b in outcome.run.backends if b.status == 'failed']
    assert failed.error is not None
    assert (failed.error.topic, failed.error.seq) == (CAMERAS[1], 30)
    assert 'the detector broke' in failed.error.message
    assert all(b.closed for b in made)  # every instance of both backends closed
    other = [r for r in outcome.records if r.backend == 'other']
    assert len(other) == 4 * FRAMES - LATE_FRAMES


def test_per_topic_over_one_camera_topic_is_shared_and_says_so_once(tmp_path: Path) -> None:
    from replaybench.fixtures.writer import write_mcap

    bag = write_mcap(tmp_path / 'one.mcap', 12, (64, 48), 'jpeg')
    made: list[Waiting] = []
    per_topic = _run(bag, tmp_path / 'p', 'per-topic', Rate('recorded'), made)
    shared = _run(bag, tmp_path / 's', 'shared', Rate('recorded'), [])
    assert len(made) == 1
    lines = [w for w in per_topic.run.warnings if '--pipelines' in w]
    assert lines == [
        (
            '--pipelines per-topic: the inputs hold one camera topic '
            '(/camera/image_raw/compressed): replayed as --pipelines shared'
        )
    ]
    assert per_topic.run.settings.pipelines.pipelines == 1
    for file in ('frames.csv', 'outputs.mcap'):
        assert (tmp_path / 'p' / file).read_bytes() == (tmp_path / 's' / file).read_bytes()
    assert shared.run.settings.pipelines is None
