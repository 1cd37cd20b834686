"""Score the exported blobs detector and the hsv backend on held-out frames.

Usage (from the repository root)::

    python training/evaluate_blobs.py [--model replaybench/models/blobs.onnx] [--frames 300]

Held-out sets: every committed fixture bag in ``fixtures/bags`` (read through
``replaybench.sources`` / ``replaybench.decode``; seed ``DEFAULT_SEED``, cameras 0 and 1,
10 frames each), and ``--frames`` frames per camera of the same two scenes rendered
directly (a larger sample of the same held-out scenes). Detections: conf 0.25, class-aware
NMS IoU 0.45 (this script's own decoding), and the same model through the ``onnx-cpu``
backend where it is installed; scores with ``replaybench.results.accuracy.evaluate``.
Needs onnxruntime, not torch.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from blobs_common import decode_output, letterbox

from replaybench.fixtures.scene import DEFAULT_SEED, Scene
from replaybench.results.accuracy import AccuracyResult, evaluate

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    import numpy.typing as npt

    from replaybench.types import Detection

REPO = Path(__file__).resolve().parents[1]
BAGS = ('rgb8_raw.mcap', 'jpeg.mcap', 'bgr8_rosbag2', 'rgb8.bag', 'two_camera.mcap')

Key = tuple[str, str, int]


def bag_frames(path: Path) -> Iterator[tuple[Key, npt.NDArray[np.uint8], tuple[Detection, ...]]]:
    """(key, BGR image, ground truth) per image of a bag; key = (bag, frame_id, stamp)."""
    from replaybench.decode import decode_detections, decode_image, to_bgr8
    from replaybench.sources import open_source

    images: dict[Key, npt.NDArray[np.uint8]] = {}
    truth: dict[Key, tuple[Detection, ...]] = {}
    with open_source(path) as source:
        for msg in source.messages():
            if msg.msgtype.endswith('Detection2DArray'):
                gt = decode_detections(msg)
                truth[(path.name, gt.frame_id, gt.stamp_ns)] = gt.detections
            elif msg.msgtype.endswith(('/Image', '/CompressedImage')):
                decoded = decode_image(msg)
                key = (path.name, decoded.frame_id, decoded.stamp_ns)
                images[key] = np.ascontiguousarray(to_bgr8(decoded.image, decoded.encoding))
    for key, image in images.items():
        yield key, image, truth[key]


def rendered_frames(
    frames: int,
) -> Iterator[tuple[Key, npt.NDArray[np.uint8], tuple[Detection, ...]]]:
    """Frames 0..frames-1 of the fixture scenes (DEFAULT_SEED, cameras 0 and 1), 320x240."""
    for camera in (0, 1):
        scene = Scene((320, 240), camera, DEFAULT_SEED)
        for i in range(frames):
            image, truth = scene.render(i)
            yield (f'render/cam{camera}', '', i), image, tuple(truth)


def onnx_detector(model: Path, threads: int = 2) -> Callable[[Any], list[Detection]]:
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.add_session_config_entry('session.intra_op.allow_spinning', '0')
    session = ort.InferenceSession(str(model), options, providers=['CPUExecutionProvider'])

    def detect(bgr: npt.NDArray[np.uint8]) -> list[Detection]:
        canvas, box = letterbox(bgr)
        x = canvas.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255.0)
        (output,) = session.run(['output0'], {'images': x})
        return decode_output(output, box, conf=0.25, iou=0.45)

    return detect


def hsv_detector() -> Callable[[Any], list[Detection]]:
    from replaybench.backends.base import BackendOptions
    from replaybench.backends.hsv import HsvBackend
    from replaybench.types import Frame

    backend = HsvBackend(BackendOptions())
    backend.open()

    def detect(bgr: npt.NDArray[np.uint8]) -> list[Detection]:
        frame = Frame('/eval', 0, 0, 0, '', bgr, 'bgr8', 'bgr8')
        return list(backend.detect(frame).detections)

    return detect


def backend_detector(model: Path, threads: int = 2) -> Callable[[Any], list[Detection]] | None:
    """The ``onnx-cpu`` backend on ``model``; None where that backend is not installed."""
    try:
        from replaybench.backends.onnx_cpu import OnnxCpuBackend
    except ImportError:
        return None
    from replaybench.backends.base import BackendOptions
    from replaybench.types import Frame

    backend = OnnxCpuBackend(BackendOptions(threads=threads, model=model))
    backend.open()

    def detect(bgr: npt.NDArray[np.uint8]) -> list[Detection]:
        frame = Frame('/eval', 0, 0, 0, '', bgr, 'bgr8', 'bgr8')
        return list(backend.detect(frame).detections)

    return detect


def score(
    detect: Callable[[Any], list[Detection]],
    frames: list[tuple[Key, npt.NDArray[np.uint8], tuple[Detection, ...]]],
) -> tuple[AccuracyResult, float]:
    """Accuracy and mean detect time in ms over ``frames``."""
    gt: dict[Key, tuple[Detection, ...]] = {}
    dets: dict[Key, list[Detection]] = {}
    elapsed = 0.0
    for key, image, truth in frames:
        start = time.perf_counter()
        dets[key] = detect(image)
        elapsed += time.perf_counter() - start
        gt[key] = truth
    return evaluate(gt, dets), elapsed / max(len(frames), 1) * 1e3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--model', type=Path, default=REPO / 'replaybench/models/blobs.onnx')
    parser.add_argument('--bags', type=Path, default=REPO / 'fixtures/bags')
    parser.add_argument('--frames', type=int, default=300, help='rendered frames per camera')
    parser.add_argument('--json', type=Path, help='also write the numbers here')
    args = parser.parse_args(argv)

    sets: dict[str, list[tuple[Key, Any, tuple[Detection, ...]]]] = {}
    for name in BAGS:
        sets[name] = list(bag_frames(args.bags / name))
    sets['all fixture bags'] = [item for name in BAGS for item in sets[name]]
    if args.frames:
        sets[f'rendered 2x{args.frames}'] = list(rendered_frames(args.frames))
    detectors = {'blobs.onnx': onnx_detector(args.model), 'hsv': hsv_detector()}
    if (via_backend := backend_detector(args.model)) is not None:
        detectors['onnx-cpu backend'] = via_backend

    rows: list[dict[str, Any]] = []
    print(
        '| set | detector | frames | gt | det | mAP@0.5 | mAP@0.5:0.95 | P@0.5 | R@0.5 | ms/frame |'
    )
    print('|---|---|---|---|---|---|---|---|---|---|')
    for set_name, frames in sets.items():
        for det_name, detect in detectors.items():
            acc, ms = score(detect, frames)
            rows.append(
                {
                    'set': set_name,
                    'detector': det_name,
                    'frames': len(frames),
                    'n_gt': acc.n_gt,
                    'n_det': acc.n_det,
                    'map50': acc.map50,
                    'map50_95': acc.map50_95,
                    'precision50': acc.precision50,
                    'recall50': acc.recall50,
                    'ap50': acc.ap50,
                    'ms_per_frame': ms,
                }
            )
            print(
                f'| {set_name} | {det_name} | {len(frames)} | {acc.n_gt} | {acc.n_det} | '
                f'{acc.map50:.3f} | {acc.map50_95:.3f} | {acc.precision50:.3f} | '
                f'{acc.recall50:.3f} | {ms:.2f} |',
                flush=True,
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + '\n', encoding='utf-8')
    return 0


if __name__ == '__main__':
    sys.exit(main())
