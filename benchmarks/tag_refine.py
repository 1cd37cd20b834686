"""Corner refinement of the tag backends: accuracy against time, per refinement.

    python -m benchmarks.tag_refine [--repeats 3] [--real ../shared/real] [--out PATH]

Each refinement of the ``aruco`` backend (``none``, ``subpix``, ``contour``, ``apriltag``) and,
for reference, each of the ``apriltag`` backend (``edges``, ``none``) is run through the
backend itself (``detect``: grey conversion, detection, undistortion and pose) on:

* the tag fixtures with exact truth: ``fixtures/tags/tags.mcap`` and ``live_tags.mcap``
  (plumb_bob, 10 frames each) and a 30-frame ``tags_fisheye.mcap`` written here
  (``write_tag_mcap``, equidistant): recall, corner RMSE (px), translation error (mm) and
  rotation error (degrees) against the bags' ``/ground_truth/tags``, and ms per frame;
* ``tags_duckietown/`` (15 real photos, 1056x792, one tag36h11 tag of 0.065 m on a turntable;
  PROVENANCE.md): the photos carry no corner or pose truth, only that one tag sits at one
  distance while its in-plane angle takes the value in the file name. Measured: photos where
  it is found; its corners' RMSE from AprilTag 3's with edge refinement (agreement with the
  reference detector, not truth); the spread of the distance (standard deviation over the
  mean: truth 0); the error of each photo's rotation from the 0-degree photo against the
  angle difference the file names give; ms per frame;
* ``bags/ros1/ubiquity_aruco_images.bag`` (one 1280x960 photo of seven ``aruco_5x5_1000``
  markers, no truth): the ids found and ms per frame (``aruco`` only; the family is not one
  AprilTag 3 decodes).

Times: the median over ``--repeats`` passes of each frame's ``detect`` time, then the mean over
the frames (the ubiquity photo: the median of ``--repeats`` x 5 detections); one OpenCV
thread, one AprilTag thread, decimation at each backend's default (aruco 1, apriltag 2).
Accuracy does not depend on the machine; times do: compare refinements within one run.
Writes benchmarks/results/tag_refine.json and prints the table. Not part of
``python -m benchmarks``: it measures accuracy as much as speed.
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib.util
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmarks.core import fix_threads, pin_thread_env

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.fiducials.types import TagDetection
    from replaybench.types import Frame

__all__ = ['DEFAULT_OUT', 'REFINEMENTS', 'main']

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / 'benchmarks' / 'results' / 'tag_refine.json'
DEFAULT_REAL = ROOT.parent / 'shared' / 'real'
#: (backend, refine) in the table's order
REFINEMENTS: tuple[tuple[str, str], ...] = (
    ('aruco', 'none'),
    ('aruco', 'subpix'),
    ('aruco', 'contour'),
    ('aruco', 'apriltag'),
    ('apriltag', 'none'),
    ('apriltag', 'edges'),
)
FIXTURE_SIZES = {'tag_size': '0.16', 'tag_sizes': '14=0.2,3=0.1'}
DUCKIE_SIZE = '0.065'
UBIQUITY_FAMILY = 'aruco_5x5_1000'


def _bag_frames(path: Path) -> list[tuple[Frame, tuple[TagDetection, ...]]]:
    """Each image of a tag bag with its CameraInfo and its truth tags."""
    from replaybench.decode import decode_camera_info, decode_image
    from replaybench.fiducials.msgs import decode_tag_array
    from replaybench.sources import open_source

    source = open_source(path)
    infos = {}
    truth = {}
    images = []
    for raw in source.messages():
        if raw.topic == '/camera/camera_info':
            info = decode_camera_info(raw)
            infos[info.stamp_ns] = info
        elif raw.topic == '/ground_truth/tags':
            found = decode_tag_array(raw)
            truth[found.stamp_ns] = found.tags
        elif raw.topic == '/camera/image_raw':
            images.append(decode_image(raw))
    source.close()
    return [(f._replace(camera_info=infos[f.stamp_ns]), truth[f.stamp_ns]) for f in images]


def _backend(name: str, refine: str, extra: dict[str, str]) -> Any:
    from replaybench.backends import get_backend
    from replaybench.backends.base import BackendOptions

    cls = get_backend(name)
    backend = cls(BackendOptions(threads=1, extra={**extra, 'refine': refine}))  # type: ignore[call-arg]
    backend.open()
    return backend


def _timed(backend: Any, frames: Sequence[Frame], repeats: int) -> tuple[list[Any], float]:
    """Each frame's result (of the first pass) and the mean over frames of the median time."""
    times: list[list[float]] = [[] for _ in frames]
    results: list[Any] = []
    for r in range(repeats):
        for i, frame in enumerate(frames):
            t0 = time.perf_counter()
            result = backend.detect(frame)
            times[i].append((time.perf_counter() - t0) * 1e3)
            if r == 0:
                results.append(result)
    return results, statistics.fmean(statistics.median(t) for t in times)


def _fixture_row(
    name: str, refine: str, frames: Sequence[tuple[Frame, tuple[TagDetection, ...]]], repeats: int
) -> dict[str, Any]:
    from replaybench.tasks.tags.scoring import score_frame, tag_accuracy

    backend = _backend(name, refine, FIXTURE_SIZES)
    results, ms = _timed(backend, [f for f, _ in frames], repeats)
    backend.close()
    scores = [score_frame(r.tags, t) for r, (_, t) in zip(results, frames, strict=True)]
    acc = tag_accuracy(scores)
    return {
        'backend': name,
        'refine': refine,
        'matched': acc.matched,
        'truth': acc.n_truth,
        'wrong_ids': acc.wrong_ids,
        'phantoms': acc.phantoms,
        'corner_rmse_px': acc.corner_rmse_px,
        'trans_err_mm': None if acc.trans_err_m is None else acc.trans_err_m * 1e3,
        'trans_err_mm_max': None if acc.trans_err_m_max is None else acc.trans_err_m_max * 1e3,
        'rot_err_deg': acc.rot_err_deg,
        'rot_err_deg_max': acc.rot_err_deg_max,
        'ms_per_frame': ms,
    }


def _duckie_frames(folder: Path) -> list[tuple[int, Frame]]:
    """(in-plane angle in degrees, frame with the photos' CameraInfo) of each photo."""
    import cv2
    import numpy as np
    from ruamel.yaml import YAML

    from replaybench.types import CameraInfo, Frame

    spec = YAML(typ='safe').load((folder / 'test_info.yaml').read_text(encoding='utf-8'))
    spec = spec['rotation_test']
    k = tuple(float(v) for v in spec['K'])
    width, height = int(spec['width']), int(spec['height'])
    info = CameraInfo(
        0,
        'camera',
        width,
        height,
        'plumb_bob',
        (0.0,) * 5,
        k,
        (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
        (k[0], 0.0, k[2], 0.0, 0.0, k[4], k[5], 0.0, 0.0, 0.0, 1.0, 0.0),
    )
    out: list[tuple[int, Frame]] = []
    for name in spec['files']:
        angle = int(name.removeprefix('test_image_rotation_').removesuffix('.png'))
        image = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        frame = Frame(
            '/duckietown',
            len(out),
            0,
            0,
            'camera',
            np.ascontiguousarray(image),
            'mono8',
            'mono8',
            camera_info=info,
        )
        out.append((angle, frame))
    return sorted(out, key=lambda item: item[0])


def _rotation_deg(a: Any, b: Any) -> float:
    from replaybench.fiducials.pose import rotation_error_deg

    return rotation_error_deg(a, b)


def _duckie_row(
    name: str,
    refine: str,
    photos: Sequence[tuple[int, Frame]],
    reference: dict[int, TagDetection],
    repeats: int,
) -> dict[str, Any]:
    import numpy as np

    backend = _backend(name, refine, {'tag_size': DUCKIE_SIZE})
    results, ms = _timed(backend, [f for _, f in photos], repeats)
    backend.close()
    found: dict[int, TagDetection] = {}
    for (angle, _), result in zip(photos, results, strict=True):
        tags = [t for t in result.tags if t.pose is not None]
        if len(tags) == 1:
            found[angle] = tags[0]
    corner = [
        float(np.mean(np.sum(np.subtract(tag.corners, reference[a].corners) ** 2, axis=1)))
        for a, tag in found.items()
        if a in reference
    ]
    ranges = [float(np.linalg.norm(t.pose.position)) for t in found.values() if t.pose]
    rotation = []
    base = found.get(0)
    if base is not None and base.pose is not None:
        for angle, tag in found.items():
            if angle and tag.pose is not None:
                rotation.append(abs(_rotation_deg(base.pose, tag.pose) - abs(angle)))
    return {
        'backend': name,
        'refine': refine,
        'found': len(found),
        'photos': len(photos),
        'corner_rms_from_apriltag_px': math.sqrt(statistics.fmean(corner)) if corner else None,
        'range_m_mean': statistics.fmean(ranges) if ranges else None,
        'range_spread_pct': (
            statistics.pstdev(ranges) / statistics.fmean(ranges) * 100 if ranges else None
        ),
        'turn_err_deg': statistics.fmean(rotation) if rotation else None,
        'turn_err_deg_max': max(rotation) if rotation else None,
        'ms_per_frame': ms,
    }


def _ubiquity_row(refine: str, bag: Path, repeats: int) -> dict[str, Any]:
    from replaybench.decode import decode_camera_info, decode_image
    from replaybench.sources import open_source

    source = open_source(bag)
    info = decode_camera_info(next(source.messages(topics=['/raspicam_node/camera_info'])))
    raw = next(source.messages(topics=['/raspicam_node/image/compressed']))
    frame = decode_image(raw)._replace(camera_info=info)
    source.close()
    backend = _backend('aruco', refine, {'family': UBIQUITY_FAMILY, 'tag_size': '0.14'})
    results, ms = _timed(backend, [frame] * 5, repeats)
    backend.close()
    return {
        'backend': 'aruco',
        'refine': refine,
        'ids': sorted(t.tag_id for t in results[0].tags),
        'ms_per_frame': ms,
    }


def _fmt(value: Any, spec: str) -> str:
    return '-' if value is None else format(value, spec)


def _fixture_line(row: dict[str, Any]) -> str:
    return (
        f'  {row["backend"]:8} {row["refine"]:8} {row["matched"]}/{row["truth"]}  '
        f'{_fmt(row["corner_rmse_px"], ".3f")}  {_fmt(row["trans_err_mm"], ".2f")} '
        f'({_fmt(row["trans_err_mm_max"], ".1f")})  {_fmt(row["rot_err_deg"], ".2f")} '
        f'({_fmt(row["rot_err_deg_max"], ".2f")})  {row["ms_per_frame"]:.1f}'
    )


def _duckie_line(row: dict[str, Any]) -> str:
    return (
        f'  {row["backend"]:8} {row["refine"]:8} {row["found"]}/{row["photos"]}  '
        f'{_fmt(row["corner_rms_from_apriltag_px"], ".3f")}  '
        f'{_fmt(row["range_spread_pct"], ".2f")}  {_fmt(row["turn_err_deg"], ".2f")} '
        f'({_fmt(row["turn_err_deg_max"], ".2f")})  {row["ms_per_frame"]:.1f}'
    )


def _table(document: dict[str, Any]) -> str:
    lines = [
        'fixtures (truth): backend refine  recall  corner px  trans mm (max)  rot deg (max)  ms'
    ]
    lines += [_fixture_line(row) for row in document['fixtures']]
    if document.get('duckietown'):
        lines.append(
            'duckietown: backend refine  found  corner px from apriltag  range spread %  '
            'turn err deg (max)  ms'
        )
        lines += [_duckie_line(row) for row in document['duckietown']]
    if document.get('ubiquity'):
        lines.append('ubiquity (1280x960): refine  ids  ms')
        lines += [
            f'  {row["refine"]:8} {len(row["ids"])}  {row["ms_per_frame"]:.1f}'
            for row in document['ubiquity']
        ]
    return '\n'.join(lines)


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog='python -m benchmarks.tag_refine', description=__doc__)
    parser.add_argument('--repeats', type=int, default=3, help='passes over each frame set')
    parser.add_argument('--real', type=Path, default=DEFAULT_REAL, help='the shared real data')
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT)
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Measure every refinement, print the table and write the JSON document."""
    pin_thread_env()
    args = _parse(argv)
    threads = fix_threads()
    from replaybench.fixtures.tags import write_tag_mcap

    refinements = [
        (b, r)
        for b, r in REFINEMENTS
        if b != 'apriltag' or importlib.util.find_spec('pupil_apriltags') is not None
    ]
    with tempfile.TemporaryDirectory() as tmp:
        fisheye = write_tag_mcap(Path(tmp) / 'tags_fisheye.mcap', 30, distortion='equidistant')
        bags = [
            ROOT / 'fixtures' / 'tags' / 'tags.mcap',
            ROOT / 'fixtures' / 'tags' / 'live_tags.mcap',
            fisheye,
        ]
        frames = [item for bag in bags for item in _bag_frames(bag)]
    document: dict[str, Any] = {
        'date': dt.date.today().isoformat(),
        'repeats': args.repeats,
        'threads': threads,
        'fixture_frames': len(frames),
        'fixtures': [_fixture_row(b, r, frames, args.repeats) for b, r in refinements],
        'duckietown': [],
        'ubiquity': [],
    }
    duckie = args.real / 'tags_duckietown'
    if duckie.is_dir() and importlib.util.find_spec('pupil_apriltags') is not None:
        photos = _duckie_frames(duckie)
        ref = _backend('apriltag', 'edges', {'tag_size': DUCKIE_SIZE})
        reference = {}
        for angle, frame in photos:
            tags = ref.detect(frame).tags
            if len(tags) == 1:
                reference[angle] = tags[0]
        ref.close()
        document['duckietown'] = [
            _duckie_row(b, r, photos, reference, args.repeats) for b, r in refinements
        ]
    bag = args.real / 'bags' / 'ros1' / 'ubiquity_aruco_images.bag'
    if bag.is_file():
        document['ubiquity'] = [
            _ubiquity_row(r, bag, args.repeats) for b, r in refinements if b == 'aruco'
        ]
    print(_table(document))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(document, indent=1) + '\n', encoding='utf-8')
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
