"""The stereo library: rectification time of raw 752x480 pairs, SGBM's accuracy.

    python -m benchmarks.bench_stereo [--pairs 300] [--out PATH]

* **rectification**: ``Rectifier.rectify`` (``replaybench.stereo``), with the fixed-point maps
  (the default) and with ``rectify_maps=float``, on raw 752x480 grey
  pairs, its maps built once beforehand (the build is timed apart), against a bare loop of the
  two ``cv2.remap`` calls with the same maps on the same pairs, in one run: per pair the median
  over ``--pairs`` (the pairs cycled), and the ratio of the two. The pairs and calibration are
  EuRoC's (``../shared/real/euroc_micro``: cam0/cam1, K, D, and R, P from ``cv2.stereoRectify``
  of ``T_BS``) where present, else the raw stereo fixture rendered at 752x480.
* **replay against a bare loop**: ``replaybench run BAG --backend sgbm --rate max`` (in process,
  kept in memory, 2 warm-up pairs) on the same pairs written into an MCAP with their CameraInfo,
  against a bare loop of the same library calls on the pairs decoded beforehand (rectify, the
  grey conversion, ``StereoSGBM.compute``, fixed point to float): the time per pair of each
  (the replay's from its throughput, the loop's its mean), the ratio replay / bare per round,
  ``--rounds`` rounds alternating which goes first, and their median (target <= 1.05x).
* **sgbm accuracy**: ``Matcher('sgbm')`` at stereo_image_proc's defaults on the rectified stereo
  fixture (16 pairs of 320x240, the figures pooled over all pixels) and on Middlebury's
  Motorcycle (``../shared/real/stereo/motorcycle``, where present): EPE, bad-2, D1-all, density.

The machine is shared: the 1-minute load average is written beside the times. Writes
benchmarks/results/stereo.json and prints the figures.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / 'benchmarks' / 'results' / 'stereo.json'
SHARED = REPO.parent / 'shared' / 'real'
SIZE = (752, 480)


def _pairs_and_infos(count: int) -> tuple[list[tuple[Any, Any]], tuple[Any, Any], str]:
    euroc = SHARED / 'euroc_micro'
    if euroc.is_dir():
        sys.path.insert(0, str(REPO / 'tests'))
        from stereodata import euroc_camera_infos, euroc_pair

        return [euroc_pair(i) for i in range(min(count, 95))], euroc_camera_infos(), 'euroc_micro'
    from replaybench.fixtures.stereo import raw_camera_infos, render_raw

    views = [render_raw(SIZE, i) for i in range(min(count, 8))]
    return [(v.left, v.right) for v in views], raw_camera_infos(SIZE, 0), 'stereo fixture'


def rectification(pairs_wanted: int) -> dict[str, Any]:
    import cv2

    from replaybench.stereo import stereo_pair

    pairs, infos, source = _pairs_and_infos(pairs_wanted)
    pair = stereo_pair(*infos)
    start = time.perf_counter_ns()
    rectifier = pair.rectifier()
    build_ms = (time.perf_counter_ns() - start) / 1e6
    maps_left, maps_right = rectifier._left, rectifier._right
    assert maps_left is not None
    assert maps_right is not None

    floating = pair.rectifier('float')

    def ours(left: Any, right: Any) -> None:
        rectifier.rectify(left, right)

    def ours_float(left: Any, right: Any) -> None:
        floating.rectify(left, right)

    def bare(left: Any, right: Any) -> None:
        cv2.remap(left, *maps_left, cv2.INTER_LINEAR)
        cv2.remap(right, *maps_right, cv2.INTER_LINEAR)

    times: dict[str, list[float]] = {'ours': [], 'bare': [], 'float': []}
    for _ in range(20):  # warm-up
        ours(*pairs[0])
        bare(*pairs[0])
        ours_float(*pairs[0])
    calls = (('ours', ours), ('bare', bare), ('float', ours_float))
    for i in range(pairs_wanted):
        left, right = pairs[i % len(pairs)]
        for name, fn in calls[i % 3 :] + calls[: i % 3]:  # each first in a third of the pairs
            t0 = time.perf_counter_ns()
            fn(left, right)
            times[name].append((time.perf_counter_ns() - t0) / 1e6)
    med = {name: statistics.median(values) for name, values in times.items()}
    return {
        'source': source,
        'size': list(SIZE),
        'pairs': pairs_wanted,
        'maps_build_ms': round(build_ms, 2),
        'rectify_ms_median': round(med['ours'], 3),
        'bare_remap_ms_median': round(med['bare'], 3),
        'rectify_ms_min': round(min(times['ours']), 3),
        'bare_remap_ms_min': round(min(times['bare']), 3),
        'ratio': round(med['ours'] / med['bare'], 3),
        'rectify_float_maps_ms_median': round(med['float'], 3),
        'rectify_float_maps_ms_min': round(min(times['float']), 3),
        'float_over_fixed': round(med['float'] / med['ours'], 3),
        'target_ms': 1.5,
        'opencv_threads': cv2.getNumThreads(),
    }


def _pairs_bag(pairs: list[tuple[Any, Any]], infos: tuple[Any, Any], where: Path) -> Path:
    from dataclasses import replace

    from replaybench.fixtures.writer import FixtureMessage, write_ros2_mcap
    from replaybench.msgs import CAMERA_INFO, IMAGE, serialize_camera_info, serialize_image

    messages = []
    for i, pair in enumerate(pairs):
        stamp = 1_700_000_000_000_000_000 + i * 50_000_000
        for side, info, image in zip(('left', 'right'), infos, pair, strict=True):
            data = serialize_camera_info(replace(info, stamp_ns=stamp), seq=i)
            messages.append(FixtureMessage(stamp, f'/cam/{side}/camera_info', CAMERA_INFO, data))
            data = serialize_image(stamp, info.frame_id, image, 'mono8', seq=i)
            messages.append(FixtureMessage(stamp, f'/cam/{side}/image_raw', IMAGE, data))
    return write_ros2_mcap(where / 'pairs.mcap', messages)


def replay_against_bare(rounds: int) -> dict[str, Any]:
    import tempfile

    import replaybench as rb
    from replaybench.stereo import Matcher, stereo_pair, to_mono8
    from replaybench.stereo.matchers import fixed_to_float

    pairs, infos, source = _pairs_and_infos(95)
    matcher = Matcher('sgbm')
    rectifier = stereo_pair(*infos).rectifier()
    warmup = 2

    def bare() -> float:
        for left, right in pairs[:warmup]:
            matcher.compute(*rectifier.rectify(left, right))
        t0 = time.perf_counter()
        for left, right in pairs[warmup:]:
            rect_left, rect_right = rectifier.rectify(left, right)
            fixed = matcher.compute_fixed(
                to_mono8(rect_left, 'mono8'), to_mono8(rect_right, 'mono8')
            )
            fixed_to_float(fixed, matcher.params.min_disparity)
        return (time.perf_counter() - t0) * 1000 / (len(pairs) - warmup)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        bag = _pairs_bag(pairs, infos, Path(tmp))

        def replay() -> float:
            result = rb.run(bag, backends=['sgbm'], out=None, warmup=warmup, report=False)
            (row,) = result.summary_rows
            assert row.throughput_fps is not None
            return 1000.0 / row.throughput_fps

        for r in range(rounds):
            order = (('bare', bare), ('replay', replay)) if r % 2 == 0 else (
                ('replay', replay), ('bare', bare))  # fmt: skip
            times = {name: fn() for name, fn in order}
            rows.append(
                {
                    'bare_ms_per_pair': round(times['bare'], 3),
                    'replay_ms_per_pair': round(times['replay'], 3),
                    'ratio': round(times['replay'] / times['bare'], 4),
                }
            )
    return {
        'source': source,
        'pairs': len(pairs),
        'warmup': warmup,
        'rounds': rows,
        'ratio_median': statistics.median(r['ratio'] for r in rows),
        'target': 1.05,
    }


def _figures(counts: Any) -> dict[str, Any]:
    f = counts.figures()
    return {k: round(getattr(f, k), 4) for k in ('epe', 'bad2', 'd1_all', 'density')}


def accuracy() -> dict[str, Any]:
    import cv2
    import numpy as np

    from replaybench.fixtures.stereo import render_stereo
    from replaybench.stereo import DisparityCounts, Matcher, score_disparity, to_mono8

    sgbm = Matcher('sgbm')
    total = DisparityCounts()
    for i in range(16):
        view = render_stereo((320, 240), i)
        total = total + score_disparity(sgbm.compute(view.left, view.right), view.disparity)
    out: dict[str, Any] = {'fixture_320x240_16_pairs': _figures(total)}
    moto = SHARED / 'stereo' / 'motorcycle'
    if moto.is_dir():
        left = to_mono8(np.asarray(cv2.imread(str(moto / 'motorcycle_left.png'))), 'bgr8')
        right = to_mono8(np.asarray(cv2.imread(str(moto / 'motorcycle_right.png'))), 'bgr8')
        truth = np.load(moto / 'motorcycle_disp.npz')['arr_0']
        t0 = time.perf_counter()
        disparity = sgbm.compute(left, right)
        out['motorcycle_741x500'] = {
            **_figures(score_disparity(disparity, truth)),
            'sgbm_ms': round((time.perf_counter() - t0) * 1000, 1),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--pairs', type=int, default=300)
    parser.add_argument('--out', type=Path, default=OUT)
    parser.add_argument('--rounds', type=int, default=5)
    args = parser.parse_args(argv)
    result = {
        'when': dt.datetime.now(dt.UTC).isoformat(timespec='seconds'),
        'load_average_1min_before': round(os.getloadavg()[0], 2),
        'cpus': os.cpu_count(),
        'rectification': rectification(args.pairs),
        'replay_against_bare': replay_against_bare(args.rounds),
        'sgbm': accuracy(),
        'load_average_1min_after': round(os.getloadavg()[0], 2),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + '\n')
    print(json.dumps(result, indent=2))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
