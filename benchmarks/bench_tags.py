"""Item t: the apriltag backend through the whole replay against a bare loop of the same
library calls.

Frames: the tag fixture (``replaybench.fixtures.tags``: three tag36h11 markers at moving poses,
640x480 mono8, plumb_bob distortion), written as an MCAP. In alternating rounds:

* bare: per frame, ``pupil_apriltags.Detector.detect`` on the grey image, then per tag
  ``cv2.undistortPoints`` (to the backend's precision, ``UNDISTORT_CRITERIA``), ``cv2.solvePnP``
  with K and ``cv2.Rodrigues``: the calls the backend makes, on images decoded beforehand, ms
  per frame;
* replay: ``run_benchmark(backends=['apriltag'])`` over the bag with the fixture's tag sizes,
  ms per frame from the frames.csv record times (first frame left out): reading, decoding,
  grey conversion, detection, undistortion and pose, boxes and tags (the tag outputs and
  scores are made after the pass).

Both sides use one AprilTag thread and decimation 2 (the backend's defaults).
Run alone: ``python -m benchmarks.bench_tags [--quick] [--out benchmarks/results/tags.json]``.
"""

from __future__ import annotations

import csv
import importlib.util
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmarks.core import (
    Check,
    Context,
    ItemResult,
    Sampler,
    interleaved,
    pin_thread_env,
    ratio,
    run_alone,
)
from replaybench.fiducials.camera import UNDISTORT_CRITERIA

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['DEFAULT_OUT', 'ITEM', 'TARGET', 'main', 'run']

ITEM = 't'
TARGET = 1.10
DEFAULT_OUT = Path(__file__).resolve().parent / 'results' / 'tags.json'
TAG_SIZES: dict[str, Any] = {'tag_size': 0.16, 'tag_sizes': '14=0.2,3=0.1'}


class _Bare:
    """The backend's library calls, written plainly, over decoded frames."""

    def __init__(self, bag: Path) -> None:
        import numpy as np
        from pupil_apriltags import Detector

        from replaybench.decode import decode_camera_info, decode_image
        from replaybench.sources import open_source

        source = open_source(bag)
        self.images = [
            np.ascontiguousarray(decode_image(m).image)
            for m in source.messages(topics=['/camera/image_raw'])
        ]
        info = decode_camera_info(next(source.messages(topics=['/camera/camera_info'])))
        source.close()
        self.k = np.asarray(info.k, dtype=np.float64).reshape(3, 3)
        self.d = np.asarray(info.d, dtype=np.float64)
        self.detector = Detector(families='tag36h11', nthreads=1, quad_decimate=2.0)
        self.sizes = {0: 0.16, 3: 0.10, 14: 0.20}
        self.np = np

    def sample(self) -> float:
        import cv2

        np = self.np
        start = time.perf_counter()
        for gray in self.images[1:]:
            for tag in self.detector.detect(gray):
                h = self.sizes.get(tag.tag_id, 0.16) / 2
                obj = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], np.float64)
                pts = (tag.corners - 0.5)[[1, 0, 3, 2]].reshape(-1, 1, 2)
                ideal = cv2.undistortPoints(
                    pts, self.k, self.d, R=np.eye(3), P=self.k, criteria=UNDISTORT_CRITERIA
                )
                _, rvec, _ = cv2.solvePnP(obj, ideal, self.k, None, flags=cv2.SOLVEPNP_ITERATIVE)
                cv2.Rodrigues(rvec)
        return (time.perf_counter() - start) / (len(self.images) - 1) * 1e3


class _Replays:
    def __init__(self, ctx: Context, bag: Path) -> None:
        self.ctx = ctx
        self.bag = bag
        self.n = 0

    def sample(self) -> float:
        from replaybench.app.run import run_config
        from replaybench.replay.runner import run_benchmark

        self.n += 1
        out = self.ctx.tmp / f'tags-run-{self.n}'
        config = run_config(
            self.bag,
            backends='apriltag',
            out=out,
            warmup=0,
            report=False,
            hash_inputs=False,
            **TAG_SIZES,
        )
        run_benchmark(config)
        with (out / 'frames.csv').open(newline='') as f:
            rows = [r for r in csv.DictReader(f) if r['status'] == 'ok'][1:]
        done = [float(r['done_s']) for r in rows]
        return (done[-1] - done[0]) / (len(done) - 1) * 1e3


def run(ctx: Context) -> ItemResult:
    title = 'apriltag replay vs a bare loop of the same library calls'
    if importlib.util.find_spec('pupil_apriltags') is None:
        return ItemResult(ITEM, title, [], [], [], skipped='pupil-apriltags not installed')
    from replaybench.fixtures.tags import write_tag_mcap

    frames = 4 if ctx.settings.quick else 60
    size = (320, 240) if ctx.settings.quick else (640, 480)  # quick: only that it runs
    bag = write_tag_mcap(ctx.tmp / 'tags.mcap', frames, size)
    from replaybench.backends.apriltag import release_detector

    bare = _Bare(bag)
    replays = _Replays(ctx, bag)
    try:
        bare_m, replay_m = interleaved(
            [
                Sampler('bare detect + undistort + solvePnP', 'ms/frame', bare.sample, frames),
                Sampler('apriltag replay', 'ms/frame', replays.sample, frames),
            ],
            ctx.settings.repeats,
        )
    finally:
        # pupil-apriltags' own __del__ frees in an order that corrupts the heap
        release_detector(bare.detector)
    checks: list[Check] = [
        ratio(ITEM, 'apriltag replay vs bare library loop', replay_m, bare_m, TARGET, op='<=')
    ]
    notes = [
        (
            f'{frames} frames of {size[0]}x{size[1]} mono8 (three tags a frame) per pass; '
            'one AprilTag thread, decimation 2, on both sides.'
        ),
        (
            'replay ms/frame = (done time of the last frame - done time of the first) / '
            '(frames - 1) from frames.csv; the bare loop leaves out the first frame too.'
        ),
    ]
    return ItemResult(ITEM, title, [bare_m, replay_m], checks, notes)


def main(argv: Sequence[str] | None = None) -> int:
    """Run item t alone, print the figures and write them as JSON."""
    pin_thread_env()
    return run_alone(
        run,
        prog='python -m benchmarks.bench_tags',
        description='apriltag replay vs a bare loop of the same library calls.',
        out=DEFAULT_OUT,
        argv=argv,
    )


if __name__ == '__main__':
    sys.exit(main())
