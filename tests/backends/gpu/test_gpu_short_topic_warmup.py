"""The replay warms a backend up on topics too short for warm-up frames: before the pass, one
detect on the topic's first frame, neither timed nor written (frames.csv, detections), so that
the first measured frame of a short topic does not pay for first-frame work (a new image size,
allocations, kernels for that shape).

Real bags (written with the mcap library), the real replay, a backend that notes what it saw.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path
from typing import Any, ClassVar

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from bagtools import image_msg, noise_frames, write_mcap

from replaybench.backends.base import Availability, BackendOptions
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.types import BackendResult, Frame, StageTimes

NS = 1_000_000_000


class Watching:
    """A backend that records the (topic, seq) of every frame it is given."""

    name: ClassVar[str] = 'watching'
    description: ClassVar[str] = 'notes its frames'

    def __init__(self) -> None:
        self.seen: list[tuple[str, int]] = []

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        self.seen.append((frame.topic, frame.seq))
        return BackendResult((), StageTimes(infer_ns=1000))

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


def _bag(path: Path, counts: dict[str, int]) -> Path:
    t0 = 1_700_000_000 * NS
    messages = []
    for topic, n in counts.items():
        frames = noise_frames(n)
        for i in range(n):
            stamp = t0 + i * NS // 10
            messages.append((topic, stamp, image_msg(stamp, frames[i]), 'sensor_msgs/msg/Image'))
    messages.sort(key=lambda m: m[1])
    write_mcap(path, messages)
    return path


def _run(tmp_path: Path, warmup: int | None) -> tuple[Watching, list[dict[str, str]]]:
    bag = _bag(tmp_path / 'short.mcap', {'/short': 4, '/long': 30})
    backend = Watching()
    config = RunConfig(
        inputs=[bag],
        backends=['watching'],
        out_dir=tmp_path / 'run',
        warmup=warmup,
        report=False,
        options=BackendOptions(),
    )
    outcome = run_benchmark(config, backend_factory=lambda name, options: backend)
    assert outcome.run_dir is not None
    with (outcome.run_dir / 'frames.csv').open(newline='', encoding='utf-8') as file:
        return backend, list(csv.DictReader(file))


def test_a_topic_under_ten_frames_gets_one_uncounted_warmup_detect(tmp_path):
    backend, rows = _run(tmp_path, None)
    short = [seq for topic, seq in backend.seen if topic == '/short']
    long = [seq for topic, seq in backend.seen if topic == '/long']
    assert short == [0, 0, 1, 2, 3]  # the first frame once more, before the pass
    assert long == list(range(30))  # 3 warm-up frames of its own, nothing extra
    assert backend.seen[0] == ('/short', 0)
    assert [r['seq'] for r in rows if r['topic'] == '/short'] == ['0', '1', '2', '3']
    assert all(r['warmup'] == '0' for r in rows if r['topic'] == '/short')
    assert sum(r['warmup'] == '1' for r in rows if r['topic'] == '/long') == 3


def test_an_explicit_warmup_is_left_as_given(tmp_path):
    backend, rows = _run(tmp_path, 0)
    assert [seq for topic, seq in backend.seen if topic == '/short'] == [0, 1, 2, 3]
    assert len(rows) == 34
