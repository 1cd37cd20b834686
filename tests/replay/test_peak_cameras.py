"""``peak --cameras`` on real rig bags (``replaybench.fixtures.rig``), on a virtual clock.

The backend declares its service time and shares a machine of ``CORES`` cores: with ``live``
instances open, a frame takes ``SERVICE_S x max(1, live / CORES)`` of its pipeline's time line
(``ThreadVirtualClock``: each pipeline's worker its own). K copies of four cameras at 30 Hz
then keep up while ``SERVICE_S x 4K / CORES`` is within a frame period, and the search must
find exactly that K.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any, ClassVar

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagtools import image_msg, noise_frames, write_mcap

from replaybench.backends.base import Availability, BackendOptions
from replaybench.errors import UsageError
from replaybench.fixtures.rig import rig_topics, write_rig_mcap
from replaybench.replay import ThreadVirtualClock
from replaybench.replay.cameras import find_peak_cameras, predicted_copies
from replaybench.replay.copies import camera_set, copy_topic, write_copies
from replaybench.results.io import read_peak_result, schema_errors
from replaybench.sources import open_source
from replaybench.types import BackendResult, Frame, StageTimes

FRAMES = 60
CORES = 2
CAMERAS = [image for image, _, _ in rig_topics(4)]
NS = 1_000_000_000


class Machine:
    """The instances open on a machine of ``cores`` cores."""

    def __init__(self, cores: int) -> None:
        self.cores = cores
        self.live = 0
        self.most = 0


class Sharing:
    """``service_s`` of virtual time per frame, stretched by the instances sharing the cores."""

    name: ClassVar[str] = 'sharing'
    description: ClassVar[str] = 'declared service time on shared cores'

    def __init__(self, clock: ThreadVirtualClock, machine: Machine, service_s: float) -> None:
        self.clock = clock
        self.machine = machine
        self.service_s = service_s

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        self.machine.live += 1
        self.machine.most = max(self.machine.most, self.machine.live)

    def detect(self, frame: Frame) -> BackendResult:
        share = max(1.0, self.machine.live / self.machine.cores)
        self.clock.advance(self.service_s * share)
        return BackendResult((), StageTimes(infer_ns=round(self.service_s * share * 1e9)))

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        self.machine.live -= 1


@pytest.fixture(scope='module')
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_rig_mcap(tmp_path_factory.mktemp('rig') / 'rig.mcap', FRAMES + 2, (64, 48), 4)


@pytest.fixture(scope='module')
def one_camera(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One raw camera at 30 Hz and nothing else: no CameraInfo."""
    path = tmp_path_factory.mktemp('one') / 'cam.mcap'
    t0 = 1_700_000_000 * NS
    stamps = [t0 + i * NS // 30 for i in range(FRAMES)]
    images = noise_frames(FRAMES, width=16, height=12)
    write_mcap(
        path,
        [
            ('/cam/image_raw', t, image_msg(t, f), 'sensor_msgs/msg/Image')
            for t, f in zip(stamps, images, strict=True)
        ],
    )
    return path


def _search(bag: Path, out: Path | None, service_s: float, **kwargs: Any) -> Any:
    clock = ThreadVirtualClock()
    machine = Machine(CORES)

    def factory(_name: str, _options: BackendOptions) -> Sharing:
        return Sharing(clock, machine, service_s)

    kwargs.setdefault('max_drop', 0.05)
    return find_peak_cameras(
        bag,
        'sharing',
        out,
        options=BackendOptions(),
        trial_frames=FRAMES,
        cores=CORES,
        clock=clock,
        backend_factory=factory,
        report=False,
        **kwargs,
    )


def _expected(service_s: float, cameras: int, max_drop: float) -> int:
    """The most copies whose stretched service time a queue of depth 1 keeps up with: drops
    of about 1 - period / stretched service once it exceeds the period."""
    period = 1 / 30
    k = 1
    while True:
        stretched = service_s * max(1.0, cameras * (k + 1) / CORES)
        if stretched > period and 1 - period / stretched > max_drop:
            return k
        k += 1


@pytest.mark.parametrize(
    ('service_s', 'max_drop', 'expected'),
    [(0.005, 0.05, 3), (0.004, 0.05, 4), (0.005, 0.2, 4), (0.002, 0.0, 8)],
)
def test_the_search_finds_exactly_the_copies_a_declared_service_time_sustains(
    rig: Path, service_s: float, max_drop: float, expected: int
) -> None:
    assert _expected(service_s, 4, max_drop) == expected
    result = _search(rig, None, service_s, max_drop=max_drop)
    cameras = result.record.cameras
    assert cameras.copies == expected
    assert result.confirmed
    assert cameras.cameras == tuple(CAMERAS)
    assert cameras.recorded_hz == pytest.approx(30.0)
    assert cameras.service_ms == pytest.approx(service_s * 1e3)
    assert cameras.predicted_copies == math.floor(CORES / (4 * 30 * service_s) + 1e-9)
    assert cameras.first_failing_copies == expected + 1
    # the count found passed two trials, the next one failed
    passed = [t.copies for t in result.trials if t.ok]
    assert passed.count(expected) == 2
    assert all(t.copies <= expected for t in result.trials if t.ok)
    assert all(t.copies > expected for t in result.trials if not t.ok)


def test_a_p99_bound_limits_the_copies_to_those_served_within_it(rig: Path) -> None:
    # 5 ms stretched by 4K / 2 pipelines per core: 10 ms a copy; p99 within 25 ms allows 2
    result = _search(rig, None, 0.005, p99_bound_ms=25.0)
    assert result.record.cameras.copies == 2
    assert result.record.cameras.first_failing_copies == 3


def test_the_prediction_is_floor_of_cores_over_cameras_rate_and_service_time() -> None:
    assert predicted_copies(2, 4, 30.0, 0.005) == 3
    assert predicted_copies(2, 4, 30.0, 0.0025) == 6  # exactly 6.0 is 6, not 5
    assert predicted_copies(16, 6, 30.0, 0.040) == 2
    assert predicted_copies(2, 4, 30.0, 0.0) is None


def test_each_copy_is_offset_by_its_share_of_a_frame_period_in_a_pipeline_of_its_own(
    rig: Path, tmp_path: Path
) -> None:
    _search(rig, tmp_path / 'peak', 0.005)
    run = json.loads((tmp_path / 'peak' / 'trials' / 'x3' / 'run.json').read_text())
    assert run['settings']['pipelines']['pipelines'] == 12
    assert run['settings']['rate'] == 'recorded'
    import csv

    with (tmp_path / 'peak' / 'trials' / 'x3' / 'frames.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    topics = {r['topic'] for r in rows}
    assert topics == {copy_topic(c, j) for c in CAMERAS for j in range(3)}
    for j in range(3):
        first = min(float(r['release_s']) for r in rows if r['topic'] == copy_topic(CAMERAS[0], j))
        assert first == pytest.approx(j / 3 / 30, abs=1e-6)
    # the copies bags are gone; every trial's run folder is kept
    peak = read_peak_result(tmp_path / 'peak')
    assert not list((tmp_path / 'peak').rglob('*.mcap'.replace('*', 'copies-*')))
    for trial in peak.trial_rows:
        assert (tmp_path / 'peak' / trial.run_dir / 'frames.csv').exists()
    assert (tmp_path / 'peak' / 'trials' / 'max' / 'run.json').exists()


def test_peak_json_of_a_camera_search_matches_the_schema_and_reads_back(
    rig: Path, tmp_path: Path
) -> None:
    from replaybench.results.io import to_json

    _search(rig, tmp_path / 'peak', 0.005)
    document = json.loads((tmp_path / 'peak' / 'peak.json').read_text())
    assert schema_errors(document, 'peak.json') == []
    assert document['cameras']['copies'] == 3
    assert document['peak_hz'] is None
    assert [t['copies'] for t in document['trials']][:1] == [3]  # starts at the prediction
    assert to_json(read_peak_result(tmp_path / 'peak')) == document
    assert document['input']['sha256'] is not None  # the bag's, from the one-camera run


def test_a_bag_of_one_camera_without_camera_info_gives_copies_of_that_camera(
    one_camera: Path,
) -> None:
    # one camera of 20 ms on 2 cores: 10 ms a copy, three copies within the 33 ms period
    result = _search(one_camera, None, 0.020)
    cameras = result.record.cameras
    assert cameras.cameras == ('/cam/image_raw',)
    assert cameras.copies == 3
    assert cameras.predicted_copies == 3


def test_the_copies_bag_holds_each_camera_and_its_camera_info_per_copy(
    rig: Path, tmp_path: Path
) -> None:
    rig_set = camera_set(rig, None)
    path = write_copies(rig, tmp_path / 'x2.mcap', 2, rig_set, 10)
    with open_source(path) as source:
        counts = {t.name: t.count for t in source.topics()}
        messages = list(source.messages())
    for j in range(2):
        for image, info, _ in rig_topics(4):
            assert counts[copy_topic(image, j)] == 10
            assert copy_topic(info, j) in counts
    times = [m.log_time_ns for m in messages]
    assert times == sorted(times)
    with open_source(rig) as source:
        original = next(m for m in source.messages([CAMERAS[1]]))
        data = bytes(original.data)
    copied = next(m for m in messages if m.topic == copy_topic(CAMERAS[1], 1))
    assert bytes(copied.data) == data
    assert copied.log_time_ns - original.log_time_ns == round(NS / 30 / 2)


def test_bad_input_for_a_camera_search_is_one_usage_error(rig: Path, tmp_path: Path) -> None:
    with pytest.raises(UsageError, match=r'no image topic /nope \(--topic\)'):
        _search(rig, None, 0.005, topics=['/nope'])
    with pytest.raises(UsageError, match='--max-copies must be at least 1'):
        _search(rig, None, 0.005, max_copies=0)
    single = tmp_path / 'single.mcap'
    t0 = 1_700_000_000 * NS
    write_mcap(
        single,
        [
            (
                '/cam/image_raw',
                t0,
                image_msg(t0, noise_frames(1, 16, 12)[0]),
                'sensor_msgs/msg/Image',
            )
        ],
    )
    with pytest.raises(UsageError, match='no camera of the bag holds two frames'):
        _search(single, None, 0.005)


def test_the_command_line_prints_the_copies_sustained_and_the_prediction(
    one_camera: Path, tmp_path: Path
) -> None:
    from typer.testing import CliRunner

    from replaybench.cli import app

    out = tmp_path / 'peak'
    args = ['peak', str(one_camera), '--backend', 'null', '--cameras', '--max-copies', '2']
    result = CliRunner().invoke(app, [*args, '--trial-frames', '20', '--out', str(out)])
    assert result.exit_code == 0, result.output
    peak = read_peak_result(out)
    rig = peak.cameras
    assert rig is not None
    # what the machine gave is its own; the lines say it as peak.json records it
    assert f'null: sustains {rig.copies or 0} x this rig (1 camera at 30 Hz)' in result.output
    assert f'predicted at most {rig.predicted_copies} x' in result.output
    assert rig.max_copies == 2
    assert all(t.copies in (1, 2) for t in peak.trial_rows)
    html = (out / 'peak.html').read_text(encoding='utf-8')
    assert f'Sustains {rig.copies or 0} × this rig' in html
    assert '<th class="n">copies</th>' in html
    assert 'Dropped frames vs copies' in html


def test_rate_limits_with_cameras_are_refused_in_one_line(one_camera: Path) -> None:
    from replaybench.app.peak import peak_config

    with pytest.raises(UsageError, match=r'--max-hz, --refine-steps limit\(s\) a rate search'):
        peak_config(one_camera, backend='null', cameras=True, max_hz=50.0, refine_steps=2)
    config = peak_config(one_camera, backend='null', cameras=True, max_copies=4)
    assert (config.cameras, config.max_copies) == (True, 4)
