"""A backend that takes frame sets (``takes_frame_sets``) gets each ``--sync`` set as one
``FrameSet``, on real bags: the rig fixture (``replaybench.fixtures.rig``: four cameras, the last
starting two frames late) and jittered two-camera bags written with ``bagtools``. On a virtual
clock the set's release (its last member's log time), its queue, its latency and what
``--rate max`` does are exact."""

from __future__ import annotations

import csv
import json
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pytest
from bagtools import image_msg, write_mcap
from mcap.reader import make_reader
from typer.testing import CliRunner

from replaybench import msgs
from replaybench.backends import BUILTIN_BACKENDS
from replaybench.backends.base import Availability, backend_traits
from replaybench.cli import app
from replaybench.errors import UsageError
from replaybench.fixtures.rig import LATE_FRAMES, rig_topics, write_rig_mcap
from replaybench.fixtures.writer import stamp_ns
from replaybench.replay import Rate, ThreadVirtualClock, VirtualClock
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.replay.sync import parse_sync
from replaybench.types import BackendResult, Detection, FrameSet, StageTimes

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.backends.base import BackendOptions

FRAMES = 30
SETS = FRAMES - LATE_FRAMES
CAMERAS = [image for image, _, _ in rig_topics(4)]
INFOS = [info for _, info, _ in rig_topics(4)]
PERIOD_S = 1 / 30
MS = 1_000_000
runner = CliRunner()
IMAGE = 'sensor_msgs/msg/Image'
DETECTIONS = msgs.DETECTION2DARRAY


def _pixels() -> np.ndarray:
    return np.full((12, 16, 3), 90, dtype=np.uint8)


class StampSpread:
    """Takes frame sets: one box per member (labelled with its topic), its output the stamp
    spread of the set in ns; waits ``service_s`` per set on the clock it is given."""

    name: ClassVar[str] = 'stamp-spread'
    description: ClassVar[str] = 'the stamp spread of a frame set'
    takes_frame_sets: ClassVar[bool] = True
    clock: ClassVar[Any] = None
    service_s: ClassVar[float] = 0.0

    def __init__(self, _options: BackendOptions | None = None) -> None:
        self.seen: list[FrameSet] = []
        self.closed = False

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame_set: FrameSet) -> BackendResult:
        assert isinstance(frame_set, FrameSet)
        if self.clock is not None:
            self.clock.advance(self.service_s)
        self.seen.append(frame_set)
        boxes = tuple(
            Detection(place, f.topic, 1.0, 0.0, 0.0, float(f.width), float(f.height))
            for place, f in enumerate(frame_set.frames)
        )
        stamps = [f.stamp_ns for f in frame_set.frames]
        return BackendResult(boxes, StageTimes(infer_ns=1), output=max(stamps) - min(stamps))

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        self.closed = True


class Single:
    """A single-frame backend beside it: notes the frames it gets."""

    name: ClassVar[str] = 'single'
    description: ClassVar[str] = 'single frames'

    def __init__(self, _options: BackendOptions | None = None) -> None:
        self.seen: list[tuple[str, int]] = []

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Any) -> BackendResult:
        assert not isinstance(frame, FrameSet)
        self.seen.append((frame.topic, frame.seq))
        return BackendResult(())

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


@pytest.fixture(scope='module')
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_rig_mcap(tmp_path_factory.mktemp('rig') / 'rig.mcap', FRAMES, (32, 24), 4)


def _run(
    bag: Path,
    *,
    sync: str | None = 'exact',
    rate: Rate | None = None,
    clock: Any = None,
    service_s: float = 0.0,
    backends: tuple[str, ...] = ('stamp-spread',),
    out: Path | None = None,
    **settings: Any,
) -> tuple[Any, dict[str, list[Any]]]:
    made: dict[str, list[Any]] = {'stamp-spread': [], 'single': []}

    class Timed(StampSpread):
        pass

    Timed.clock = clock
    Timed.service_s = service_s

    def factory(name: str, options: BackendOptions) -> Any:
        backend = Timed(options) if name == 'stamp-spread' else Single(options)
        made[name].append(backend)
        return backend

    config = RunConfig(
        inputs=[bag],
        backends=list(backends),
        out_dir=out,
        sync=None if sync is None else parse_sync(sync),
        rate=rate or Rate('max'),
        report=False,
        hash_inputs=False,
        **settings,
    )
    return run_benchmark(config, clock=clock, backend_factory=factory), made


def test_a_set_backend_gets_each_synchronised_set_as_one_frame_set_in_the_topics_order(
    rig: Path,
) -> None:
    assert backend_traits(StampSpread).takes_frame_sets
    outcome, made = _run(rig, backends=('stamp-spread', 'single'))
    (sets,) = made['stamp-spread']
    assert len(sets.seen) == SETS
    for k, frame_set in enumerate(sets.seen):
        assert frame_set.topics == tuple(CAMERAS)
        # the reference is the first topic's frame: the set's key is its
        assert (frame_set.topic, frame_set.seq) == (CAMERAS[0], k + LATE_FRAMES)
        assert frame_set.stamp_ns == stamp_ns(k + LATE_FRAMES)
        assert frame_set.frame_id == 'rig_cam0_optical_frame'
        assert [f.stamp_ns for f in frame_set.frames] == [stamp_ns(k + LATE_FRAMES)] * 4
        # every member carries its own camera's CameraInfo
        infos = [f.camera_info for f in frame_set.frames]
        assert [i.topic for i in infos if i is not None] == INFOS
        assert [i.frame_id for i in infos if i is not None] == [
            f'rig_cam{j}_optical_frame' for j in range(4)
        ]
    # the single-frame backend beside it gets every frame, the unpaired ones too
    (single,) = made['single']
    assert len(single.seen) == 4 * FRAMES - LATE_FRAMES
    rows = [r for r in outcome.records if r.backend == 'stamp_spread']
    # one row per set, keyed by its reference frame; the frames with no partner have none
    assert [(r.topic, r.seq, r.stamp_ns) for r in rows] == [
        (CAMERAS[0], k, stamp_ns(k)) for k in range(LATE_FRAMES, FRAMES)
    ]
    assert {r.detections for r in rows} == {4}
    assert outcome.run.sync.backends == {'stamp_spread': 'sets', 'single': 'frames'}
    (summary,) = [s for s in outcome.summaries if s.backend == 'stamp_spread']
    assert summary.topic == CAMERAS[0]


def test_a_set_is_released_at_its_last_members_log_time_and_its_latency_runs_from_there(
    tmp_path: Path,
) -> None:
    left = [1_700_000_000 * 10**9 + k * 33 * MS for k in range(10)]
    # the right camera's message of each set is logged 7 ms after the left one's
    messages = []
    for k, stamp in enumerate(left):
        right_stamp = stamp + (2 * MS if k % 2 else -1 * MS)
        messages.append(('/l/image_raw', stamp + 2 * MS, image_msg(stamp, _pixels()), IMAGE))
        messages.append(('/r/image_raw', stamp + 9 * MS, image_msg(right_stamp, _pixels()), IMAGE))
    bag = tmp_path / 'stereo.mcap'
    write_mcap(bag, sorted(messages, key=lambda m: (m[1], m[0])))
    clock = VirtualClock()
    outcome, made = _run(bag, sync='approx:3', rate=Rate('recorded'), clock=clock, service_s=0.004)
    (backend,) = made['stamp-spread']
    assert [s.topics for s in backend.seen] == [('/l/image_raw', '/r/image_raw')] * 10
    assert [s.latest_log_time_ns - s.log_time_ns for s in backend.seen] == [7 * MS] * 10
    # the members' stamps as recorded: the right one 1 ms early, then 2 ms late
    spreads = [s.frames[1].stamp_ns - s.stamp_ns for s in backend.seen]
    assert spreads == [2 * MS if k % 2 else -MS for k in range(10)]
    rows = outcome.records
    # the clock starts at the first message (the first left image); each set is due when
    # its right image is logged, 7 ms later
    assert [r.release_s for r in rows] == pytest.approx([k * 0.033 + 0.007 for k in range(10)])
    assert all(r.queue_wait_ms == pytest.approx(0.0, abs=1e-9) for r in rows)
    assert all(r.latency_ms == pytest.approx(4.0) for r in rows)
    stamps = [r.stamp_ns for r in rows]
    assert stamps == left  # keyed by the reference (left) frame's stamp


def test_sets_that_come_faster_than_the_backend_wait_in_one_queue_the_newest_kept(
    rig: Path,
) -> None:
    clock = VirtualClock()
    outcome, made = _run(
        rig, rate=Rate('recorded'), clock=clock, service_s=0.050, queue_depth=1, warmup=0
    )
    rows = outcome.records
    assert len(rows) == SETS
    dropped = [r for r in rows if r.dropped]
    served = [r for r in rows if r.status == 'ok']
    assert len(served) + len(dropped) == SETS
    # a set every 33.3 ms, 50 ms each: one set in service, one waiting, the rest pushed out
    assert len(served) <= SETS * PERIOD_S / 0.050 + 2
    assert len(dropped) >= 8
    # the first set is due when the late camera's first frame is logged
    assert rows[0].release_s == pytest.approx(LATE_FRAMES * PERIOD_S, abs=1e-6)
    for r in served:
        assert r.latency_ms == pytest.approx(r.queue_wait_ms + 50.0)
    (backend,) = made['stamp-spread']
    assert len(backend.seen) == len(served)


def test_at_max_rate_sets_follow_each_other_back_to_back(rig: Path) -> None:
    clock = VirtualClock()
    outcome, _ = _run(rig, rate=Rate('max'), clock=clock, service_s=0.010, warmup=0)
    rows = outcome.records
    assert len(rows) == SETS
    assert not any(r.dropped for r in rows)
    assert [r.start_s for r in rows] == pytest.approx([0.010 * k for k in range(SETS)])
    assert all(r.latency_ms == pytest.approx(10.0) for r in rows)


def test_few_sets_get_one_warm_up_set_that_is_not_recorded(tmp_path: Path) -> None:
    bag = write_rig_mcap(tmp_path / 'short.mcap', 6, (32, 24), 2)
    outcome, made = _run(bag)
    (backend,) = made['stamp-spread']
    # 4 sets: too few for warm-up sets, so one untimed detect on the first set before them
    assert len(backend.seen) == 5
    assert backend.seen[0].seq == backend.seen[1].seq == LATE_FRAMES
    assert [r.seq for r in outcome.records] == [2, 3, 4, 5]
    assert not any(r.warmup for r in outcome.records)


def test_many_sets_have_warm_up_sets_counted_in_sets(tmp_path: Path) -> None:
    bag = write_rig_mcap(tmp_path / 'long.mcap', 42, (32, 24), 2)
    outcome, _ = _run(bag)
    # 40 sets: 4 warm-up sets (a tenth), though the reference topic holds 42 frames
    assert [r.warmup for r in outcome.records] == [True] * 4 + [False] * 36


def test_results_are_written_under_the_reference_frames_key_in_outputs_mcap(
    rig: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'run'
    _outcome, _ = _run(rig, out=out, backends=('stamp-spread', 'single'))
    store = msgs.typestore()
    with (out / 'outputs.mcap').open('rb') as f:
        written: list[tuple[str, int, Any]] = [
            (channel.topic, message.log_time, store.deserialize_cdr(message.data, DETECTIONS))
            for _, channel, message in make_reader(f).iter_messages()
            if channel.topic.startswith('/replaybench/stamp_spread/')
        ]
    assert len(written) == SETS
    # on the reference camera's detections topic, at its frames' log times and stamps
    assert {topic for topic, _, _ in written} == {
        f'/replaybench/stamp_spread{CAMERAS[0]}/detections'
    }
    for k, (_, log_time, dets) in enumerate(written):
        stamp = stamp_ns(k + LATE_FRAMES)
        assert log_time == stamp
        assert dets.header.frame_id == 'rig_cam0_optical_frame'
        assert dets.header.stamp.sec * 10**9 + dets.header.stamp.nanosec == stamp
        labels = [d.results[0].hypothesis.class_id for d in dets.detections]
        assert labels == CAMERAS
    with (out / 'frames.csv').open(newline='') as f:
        rows = [r for r in csv.DictReader(f) if r['backend'] == 'stamp_spread']
    assert [(r['topic'], int(r['seq'])) for r in rows] == [
        (CAMERAS[0], k) for k in range(LATE_FRAMES, FRAMES)
    ]
    sync = json.loads((out / 'run.json').read_text())['sync']
    unpaired = {t['topic']: t['unpaired'] for t in sync['inputs'][0]['topics']}
    assert unpaired == {CAMERAS[0]: 2, CAMERAS[1]: 2, CAMERAS[2]: 2, CAMERAS[3]: 0}


def test_per_topic_pipelines_give_a_set_backend_one_pipeline_for_its_set_stream(
    rig: Path,
) -> None:
    clock = ThreadVirtualClock()
    outcome, made = _run(
        rig,
        rate=Rate('recorded'),
        clock=clock,
        backends=('stamp-spread', 'single'),
        pipelines='per-topic',
    )
    assert len(made['stamp-spread']) == 1
    assert len(made['single']) == 4  # one instance per camera, as without sets
    assert len(made['stamp-spread'][0].seen) == SETS
    said = [w for w in outcome.run.warnings if 'take(s) frame sets' in w]
    assert said == [
        (
            "--pipelines per-topic: stamp_spread take(s) frame sets of --sync: each input's set "
            f'stream ({", ".join(CAMERAS)}) is one pipeline'
        )
    ]


def test_a_set_backend_without_sync_is_refused_in_one_line_before_anything_is_read(
    rig: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(UsageError, match='only --sync makes'):
        _run(rig, sync=None)
    monkeypatch.setitem(BUILTIN_BACKENDS, 'stamp-spread', f'{__name__}:StampSpread')
    out = tmp_path / 'r'
    result = runner.invoke(
        app, ['run', str(rig), '-b', 'stamp-spread', '-b', 'null', '--out', str(out)]
    )
    assert result.exit_code == 2
    assert result.stdout == ''
    assert result.stderr.strip().splitlines() == [
        (
            "replaybench: error: backend 'stamp-spread' takes synchronised frame sets, which only "
            '--sync makes: add --sync exact (equal header stamps) or --sync approx:SLOP_MS'
        )
    ]
    assert not out.exists()
    result = runner.invoke(
        app, ['run', str(rig), '-b', 'stamp-spread', '--sync', 'exact', '--out', str(out)]
    )
    assert result.exit_code == 0, result.stderr
    assert 'unpaired frames' in result.stderr


def test_a_member_that_does_not_decode_skips_its_set_in_the_reference_frames_row(
    tmp_path: Path,
) -> None:
    stamps = [1_700_000_000 * 10**9 + k * 33 * MS for k in range(12)]
    messages = []
    for k, stamp in enumerate(stamps):
        right = (
            image_msg(stamp, _pixels(), data=b'\x00' * 7) if k == 4 else image_msg(stamp, _pixels())
        )
        messages.append(('/l/image_raw', stamp, image_msg(stamp, _pixels()), IMAGE))
        messages.append(('/r/image_raw', stamp + MS, right, IMAGE))
    bag = tmp_path / 'broken.mcap'
    write_mcap(bag, messages)
    outcome, made = _run(bag, warmup=0)
    rows = outcome.records
    assert [(r.topic, r.seq, r.status) for r in rows] == [
        ('/l/image_raw', k, 'skipped' if k == 4 else 'ok') for k in range(12)
    ]
    assert rows[4].note != ''
    (backend,) = made['stamp-spread']
    assert [s.seq for s in backend.seen] == [k for k in range(12) if k != 4]


def test_repeated_passes_give_every_set_again_with_its_pass_number(rig: Path) -> None:
    outcome, made = _run(rig, repeat=2, warmup=0)
    assert [r.repeat for r in outcome.records] == [0] * SETS + [1] * SETS
    assert len(made['stamp-spread'][0].seen) == 2 * SETS


def test_at_a_fixed_rate_the_kth_set_is_released_at_k_over_hz(rig: Path) -> None:
    outcome, _ = _run(rig, rate=Rate('fixed', hz=10.0), clock=VirtualClock(), service_s=0.001)
    assert [r.release_s for r in outcome.records] == pytest.approx([k / 10 for k in range(SETS)])
    assert not any(r.dropped for r in outcome.records)


def test_a_frame_set_holds_at_least_one_frame() -> None:
    with pytest.raises(ValueError, match='at least one frame'):
        FrameSet(())
