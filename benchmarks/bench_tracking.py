"""Item k: the trackers' cost at 50 objects against the detector alone in the same run, and
their identity figures on the tracking fixture.

Cost: a generated bag of 50 objects (640x480 JPEG, a 10 x 5 grid of coloured squares drifting
a pixel a frame, so that hsv finds 50 boxes a frame). Each round is one ``run_benchmark`` of
five instances over it, each tracked one between two of ``hsv`` alone: ``hsv``, ``hsv+sort``,
``hsv_b`` (hsv), ``hsv+bytetrack``, ``hsv_c`` (hsv); per instance its median ``latency_ms``
and its median ``track_ms`` (the tracker's own time per frame, frames.csv) over the measured
frames. The targets: SORT ≤ 0.3 ms and ByteTrack ≤ 0.5 ms per frame at 50 objects
(``track_ms``). Beside them, the latency a tracker adds to its detector: per round the tracked
instance's median latency minus the mean of the two hsv instances run just before and after
it (the later of two identical instances in a run measures faster by up to 0.1 ms, which a
difference against the first alone would count), the median over the rounds, and the
distribution-free 95 % interval of that median (order statistics); it cannot decide the
target where that interval holds it, and says so.

Identity: one run of ``hsv`` with ``--tracker iou``, ``sort`` and ``bytetrack`` over the
tracking fixture (``replaybench.fixtures.tracks``, 90 frames): IDF1, HOTA, MOTA and ID
switches of each, deterministic. ByteTrack's IDF1 must reach SORT's, and SORT's the IoU
baseline's.

Run alone:
``python -m benchmarks.bench_tracking [--quick] [--out benchmarks/results/tracking.json]``.
"""

from __future__ import annotations

import csv
import math
import statistics
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmarks.core import (
    Check,
    Context,
    ItemResult,
    Measurement,
    at_most,
    pin_thread_env,
    run_alone,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['DEFAULT_OUT', 'ITEM', 'grid_scene', 'main', 'median_interval', 'run', 'write_grid_mcap']

ITEM = 'k'
DEFAULT_OUT = Path(__file__).resolve().parent / 'results' / 'tracking.json'
OBJECTS = 50
TARGETS = {'sort': 0.3, 'bytetrack': 0.5}


def grid_scene(size: tuple[int, int] = (640, 480)) -> Any:
    """``OBJECTS`` squares on a 10 x 5 grid drifting right and down, truth with ids."""
    from replaybench.fixtures.exact import hsv_to_bgr
    from replaybench.fixtures.scene import Scene, SceneObject

    class Grid(Scene):
        def __init__(self) -> None:
            super().__init__(size, 0)
            width, height = size
            hues = (0, 60, 115, 28)
            cols, rows = 10, OBJECTS // 10
            self.objects = tuple(
                SceneObject(
                    class_index=n % 4,
                    shape='rect',
                    width=20,
                    height=20,
                    angle=0.0,
                    x=(n % cols + 0.5) * width / cols,
                    y=(n // cols + 0.5) * height / rows,
                    vx=1.0,
                    vy=0.5,
                    bgr=hsv_to_bgr(hues[n % 4], 230, 210),
                )
                for n in range(OBJECTS)
            )

    return Grid()


def write_grid_mcap(path: Path, frames: int, size: tuple[int, int] = (640, 480)) -> Path:
    """A JPEG bag of the ``grid_scene``: ``OBJECTS`` squares drifting, truth with ids."""
    return _write(path, grid_scene(size), frames, size)


def _write(path: Path, scene: Any, frames: int, size: tuple[int, int]) -> Path:
    import cv2

    from replaybench.fixtures.writer import (
        GROUND_TRUTH_TOPIC,
        JPEG_FORMAT,
        FixtureMessage,
        camera_info,
        stamp_ns,
        write_ros2_mcap,
    )
    from replaybench.msgs import (
        CAMERA_INFO,
        COMPRESSED_IMAGE,
        DETECTION2DARRAY,
        serialize_camera_info,
        serialize_compressed_image,
        serialize_detections,
    )

    def records() -> Any:
        for i in range(frames):
            stamp = stamp_ns(i)
            image, truth = scene.render(i)
            info = serialize_camera_info(camera_info(size, stamp, 'camera_optical_frame'))
            yield FixtureMessage(stamp, '/camera/camera_info', CAMERA_INFO, info)
            _, jpeg = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, 90])
            data = serialize_compressed_image(
                stamp, 'camera_optical_frame', jpeg.tobytes(), JPEG_FORMAT
            )
            yield FixtureMessage(stamp, '/camera/image_raw/compressed', COMPRESSED_IMAGE, data)
            data = serialize_detections(stamp, 'camera_optical_frame', truth)
            yield FixtureMessage(stamp, GROUND_TRUTH_TOPIC, DETECTION2DARRAY, data)

    return write_ros2_mcap(path, records())


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as f:
        return list(csv.DictReader(f))


def _medians(frames_csv: Path, backend: str) -> tuple[float, float | None, float]:
    """(median latency_ms, median track_ms, mean detections) of a backend's measured frames."""
    rows = [
        r
        for r in _rows(frames_csv)
        if r['backend'] == backend and r['status'] == 'ok' and r['warmup'] == '0'
    ]
    latency = statistics.median(float(r['latency_ms']) for r in rows)
    times = [float(r['track_ms']) for r in rows if r.get('track_ms')]
    boxes = statistics.fmean(int(r['detections']) for r in rows)
    return latency, statistics.median(times) if times else None, boxes


def median_interval(values: Sequence[float]) -> tuple[float, float]:
    """The distribution-free 95 % interval of the median of ``values``: the order statistics
    k and n + 1 - k (1-based) for the largest k whose binomial tail is at most 2.5 %; the
    extremes where there are too few values for it (n < 6)."""
    ordered = sorted(values)
    n = len(ordered)
    k, tail = 0, 0.0
    while True:  # P(X <= k) for X ~ Binomial(n, 1/2), k the next order statistic's index
        tail += math.comb(n, k) / 2**n
        if tail > 0.025 or k >= (n - 1) // 2:
            break
        k += 1
    return ordered[k - 1 if k else 0], ordered[n - k if k else n - 1]


def run(ctx: Context) -> ItemResult:
    from replaybench.app.run import run_config
    from replaybench.fixtures.tracks import write_tracks_mcap
    from replaybench.replay.runner import run_benchmark

    title = f'tracker cost at {OBJECTS} objects vs the detector alone; IDF1 on crossings'
    frames = 30 if ctx.settings.quick else 150
    grid = write_grid_mcap(ctx.tmp / 'grid.mcap', frames)
    # each tracked instance between two of hsv alone (labels: instances of hsv)
    backends = ['hsv', 'hsv+sort', 'hsv_b=hsv', 'hsv+bytetrack', 'hsv_c=hsv']
    labels = [b.split('=')[0] for b in backends]
    brackets = {'hsv+sort': ('hsv', 'hsv_b'), 'hsv+bytetrack': ('hsv_b', 'hsv_c')}
    latency: dict[str, list[float]] = {b: [] for b in labels}
    track: dict[str, list[float]] = {b: [] for b in brackets}
    boxes = 0.0
    rounds = 3 * ctx.settings.repeats  # the added latency needs more rounds than a ratio
    for n in range(1 + rounds):  # the first round warms up, discarded
        out = ctx.tmp / f'tracking-run-{n}'
        config = run_config(grid, backends=backends, out=out, report=False, hash_inputs=False)
        run_benchmark(config)
        if n == 0:
            continue
        for b in labels:
            lat, trk, boxes_b = _medians(out / 'frames.csv', b)
            latency[b].append(lat)
            if trk is not None:
                track[b].append(trk)
            if b == 'hsv':
                boxes = boxes_b
    measured = [
        Measurement(f'{b} median latency', 'ms/frame', tuple(v), frames) for b, v in latency.items()
    ] + [
        Measurement(f'{b} median track_ms', 'ms/frame', tuple(v), frames) for b, v in track.items()
    ]
    by_name = {m.name: m for m in measured}
    checks: list[Check] = []
    for b, (before, after) in brackets.items():
        tracker = b.split('+')[1]
        checks.append(
            at_most(
                ITEM,
                f'{tracker} ms/frame at {OBJECTS} objects',
                by_name[f'{b} median track_ms'],
                TARGETS[tracker],
            )
        )
        added = [
            t - (x + y) / 2
            for t, x, y in zip(latency[b], latency[before], latency[after], strict=True)
        ]
        low, high = median_interval(added)
        target = TARGETS[tracker]
        decides = 'under' if high <= target else 'over' if low > target else 'inconclusive'
        checks.append(
            Check(
                ITEM,
                f'{b} latency added to hsv',
                statistics.median(added),
                low,
                high,
                'ms',
                None,
                '<=',
                f'{b} median latency - the mean of {before} and {after}, per round; 95 % '
                'interval of the median over the rounds',
                f'against {target} ms: {decides}',
            )
        )
    # identity on the crossings: deterministic, one run
    bag = write_tracks_mcap(ctx.tmp / 'tracks.mcap')
    out = ctx.tmp / 'tracking-identity'
    names = ['hsv', 'hsv+iou', 'hsv+sort', 'hsv+bytetrack']
    run_benchmark(run_config(bag, backends=names, out=out, report=False, hash_inputs=False))
    table = {r['backend']: r for r in _rows(out / 'summary.csv')}
    idf1 = {b: float(table[b]['idf1']) for b in names[1:]}
    for b in names[1:]:
        row = table[b]
        value = float(row['idf1'])
        checks.append(Check(ITEM, f'{b} IDF1 on the crossings', value, value, value, '', None))
        for key in ('hota', 'mota', 'id_switches'):
            v = float(row[key])
            checks.append(Check(ITEM, f'{b} {key} on the crossings', v, v, v, '', None))
    gaps = (
        ('bytetrack - sort', idf1['hsv+bytetrack'] - idf1['hsv+sort']),
        ('sort - iou', idf1['hsv+sort'] - idf1['hsv+iou']),
    )
    for what, gap in gaps:
        checks.append(Check(ITEM, f'IDF1 {what} on the crossings', gap, gap, gap, '', 0.0, '>='))
    notes = [
        (
            f'cost: {frames} frames of 640x480 JPEG, {boxes:.1f} hsv boxes a frame; each of '
            f'{rounds} rounds one run of hsv, hsv+sort, hsv_b, hsv+bytetrack and hsv_c (each its '
            'own hsv instance); medians over the measured frames; the first round discarded.'
        ),
        'identity: the tracking fixture (90 frames, replaybench fixtures --tracks), one run.',
    ]
    return ItemResult(ITEM, title, measured, checks, notes)


def main(argv: Sequence[str] | None = None) -> int:
    """Run item k alone, print the figures and write them as JSON."""
    pin_thread_env()
    return run_alone(
        run,
        prog='python -m benchmarks.bench_tracking',
        description='Tracker cost at 50 objects and IDF1 on the crossing fixture.',
        out=DEFAULT_OUT,
        argv=argv,
    )


if __name__ == '__main__':
    sys.exit(main())
