"""Nothing that only the run record needs comes before the first frame: the machine is described
after the passes (its load average taken before them), and a fresh ``replaybench run`` reaches
its first frame without the record's types, OpenCV, pydantic (typer's coercion) or a ROS type
store (CameraInfo and Detection2DArray ground truth are read by hand, as images are).

Order of events and imported modules are asserted, never a duration (the figure is
benchmarks/first_frame.py's).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from replaybench.backends.null import NullBackend
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.results import machine

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'

_CHILD = """
import json, sys
from replaybench.backends.null import NullBackend
_detect = NullBackend.detect
def detect(self, frame):
    if not hasattr(NullBackend, 'seen'):
        NullBackend.seen = sorted(m for m in sys.modules if m in WATCHED)
        print('FIRST ' + json.dumps(NullBackend.seen), file=sys.stderr, flush=True)
    return _detect(self, frame)
NullBackend.detect = detect
WATCHED = set(sys.argv[1].split(','))
sys.argv = ['replaybench', *sys.argv[2:]]
from replaybench.cli import main
main()
"""

#: modules that the run record or the machine's description need, not the first frame; and the
#: ROS 2 type store, which reading CameraInfo and ground truth does not need
_LATER: tuple[str, ...] = (
    'cv2',
    'pydantic',  # typer's coercion: plain option values are read without it
    'replaybench.replay.record',
    'replaybench.results.model',
    'replaybench.results.stats',
    'replaybench.results.io',
    'replaybench.backends.gpu.cuda',
    'replaybench.backends.gpu._engines',
    'replaybench.backends.gpu._dnn',
    'rosbags.typesys.stores.ros2_humble',
    # the tasks are loaded as the inputs open (each names its truth topics), but the third-party
    # tasks are looked for without importlib.metadata where no distribution declares one
    'importlib.metadata',
    # the truth readers of tasks whose truth the input does not hold
    'replaybench.tasks.tags.truth',
    'replaybench.tasks.segmentation.truth',
    # the tasks' recorded readers: only the recorded backend reads them, before its passes
    'replaybench.tasks.detections.recorded',
    'replaybench.tasks.tags.recorded',
    'replaybench.tasks.segmentation.recorded',
    # the tasks' recordings (their scorers and sinks): made when a pass's frames are recorded
    'replaybench.tasks.tags.recording',
    'replaybench.tasks.segmentation.recording',
)

#: what a bag with box truth imports before its first frame besides: the reader of that truth
_WITH_TRUTH = ('replaybench.tasks.detections.truth',)
_LATER = (*_LATER, *_WITH_TRUTH)


def _camera_bag(path: Path) -> Path:
    """Five rgb8 frames, each with its CameraInfo, and no ground truth."""
    import numpy as np
    from mcap.writer import Writer

    from replaybench.fixtures.writer import camera_info, stamp_ns
    from replaybench.msgs import (
        CAMERA_INFO,
        IMAGE,
        ros2msg_schema,
        serialize_camera_info,
        serialize_image,
    )

    with path.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='ros2', library='tests')
        channels = {}
        for topic, msgtype in (('/cam/image_raw', IMAGE), ('/cam/camera_info', CAMERA_INFO)):
            schema = writer.register_schema(
                name=msgtype, encoding='ros2msg', data=ros2msg_schema(msgtype).encode()
            )
            channels[topic] = writer.register_channel(
                topic=topic, message_encoding='cdr', schema_id=schema
            )
        image = np.zeros((48, 64, 3), dtype=np.uint8)
        for i in range(5):
            t = stamp_ns(i)
            messages = (
                ('/cam/camera_info', serialize_camera_info(camera_info((64, 48), t, 'cam'))),
                ('/cam/image_raw', serialize_image(t, 'cam', image, 'rgb8')),
            )
            for topic, data in messages:
                writer.add_message(
                    channel_id=channels[topic], log_time=t, data=data, publish_time=t
                )
        writer.finish()
    return path


@pytest.mark.parametrize(
    ('bag_name', 'info_topic'),
    [
        ('camera.mcap', '/cam/camera_info'),  # written here: no ground truth
        ('rgb8_raw.mcap', '/camera/camera_info'),  # with ground truth on /ground_truth/detections
    ],
)
def test_a_fresh_run_reaches_its_first_frame_before_importing_what_only_the_record_needs(
    tmp_path, bag_name, info_topic
):
    bag = RAW if bag_name == RAW.name else _camera_bag(tmp_path / bag_name)
    env = {**os.environ, 'PYTHONPATH': str(REPO)}
    done = subprocess.run(
        [
            sys.executable, '-c', _CHILD, ','.join(_LATER),
            'run', str(bag), '--backend', 'null', '--no-report', '--out', str(tmp_path / 'r'),
        ],
        capture_output=True, text=True, check=False, env=env, cwd=REPO, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    (line,) = [x for x in done.stderr.splitlines() if x.startswith('FIRST ')]
    # the bag with truth reads it (only it) before the first frame; the other reads none
    assert json.loads(line.removeprefix('FIRST ')) == (list(_WITH_TRUTH) if bag == RAW else [])
    run = json.loads((tmp_path / 'r' / 'run.json').read_text(encoding='utf-8'))
    assert run['environment']['packages']['opencv']['version']  # described, after the passes
    assert run['inputs'][0]['topics'][0]['camera_info_topic'] == info_topic
    if bag == RAW:  # the truth was read (by hand) and scored
        assert run['inputs'][0]['ground_truth_frames'] == 10
        assert run['summary'][0]['recall50'] == 0.0  # the null backend finds none of it


class _Logged(NullBackend):
    events: list[str]

    def detect(self, frame):
        self.events.append('frame')
        return super().detect(frame)


def test_the_machine_is_described_after_the_passes_with_the_load_average_from_before_them(
    monkeypatch,
):
    events: list[str] = []
    loads = iter([(1.0, 2.0, 3.0)])

    def getloadavg() -> tuple[float, float, float]:
        events.append('load')
        return next(loads, (9.0, 9.0, 9.0))

    real_environment = machine.environment

    def environment() -> dict[str, object]:
        events.append('described')
        return real_environment()

    monkeypatch.setattr(os, 'getloadavg', getloadavg)
    monkeypatch.setattr(machine, 'environment', environment)
    _Logged.events = events
    outcome = run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=None, warmup=0),
        backend_factory=lambda name, options: _Logged(options),
    )
    assert events.index('load') < events.index('frame')
    assert events.index('described') > max(i for i, e in enumerate(events) if e == 'frame')
    assert outcome.run.environment.load_average == (1.0, 2.0, 3.0)
