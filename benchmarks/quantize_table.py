"""The measured table of docs/quantize.md: FP32 against INT8 (``replaybench quantize``) of the
same model, in one process, over the same held-out frames.

Rows: the bundled detector (``blobs.onnx``) and segmenter (``blobs_seg.onnx``), the 384x384
encoder-decoder of benchmark item s (random weights: agreement only), and YOLOX-Nano (opset 11,
upgraded to 13 by ``quantize``; no labels here: agreement only, on held-out real frames and on
``astronaut.png`` written into a bag). For each: the latency ratio INT8 / FP32 of
``detect`` (one intra-op thread; FP32 and INT8 interleaved, ``--repeats`` rounds, the median of
the per-round ratios and their range), the accuracy change on held-out frames with a paired
bootstrap interval over frames (mAP@0.5; mIoU for segmentation), and the output agreement (share
of FP32 boxes matched at IoU 0.5 and their mean IoU; share of mask pixels equal).

Run: ``PYTHONPATH=. .venv/bin/python -m benchmarks.quantize_table [--repeats 5] [--out FILE]``.
Where ``run --backend LABEL=NAME`` exists the same comparison is one ``run`` of two instances
(docs/quantize.md).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from benchmarks.core import Sampler, interleaved

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from replaybench.types import Frame

__all__ = ['main']

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / 'shared' / 'real'
BOOTSTRAP = 1000


def _frames(bag: Path, *, start_s: float = 0.0, end_s: float | None = None) -> list[Frame]:
    from replaybench.decode import decode_image, probe_topics
    from replaybench.sources import open_source

    with open_source(bag) as source:
        topics = [
            c.name
            for c in probe_topics(source)
            if not c.is_depth and not c.error and not c.name.startswith('/ground_truth/')
        ]
        first = min(t.first_ns for t in source.topics())
        lo = first + int(start_s * 1e9)
        hi = None if end_s is None else first + int(end_s * 1e9)
        out = []
        for raw in source.messages(topics=topics, start_ns=lo, end_ns=hi):
            frame = decode_image(raw)
            out.append(frame._replace(image=np.array(frame.image)))
    return out


def _truth(bag: Path) -> dict[int, tuple[Any, ...]]:
    from replaybench.decode import decode_detections
    from replaybench.sources import open_source

    with open_source(bag) as source:
        return {
            gt.stamp_ns: gt.detections
            for gt in (
                decode_detections(m) for m in source.messages(topics=['/ground_truth/detections'])
            )
        }


def _masks(bag: Path) -> dict[int, Any]:
    from replaybench.decode import decode_image
    from replaybench.sources import open_source

    with open_source(bag) as source:
        found = {}
        for m in source.messages(topics=['/ground_truth/labels']):
            frame = decode_image(m)
            found[frame.stamp_ns] = np.array(frame.image)
    return found


def _backend(kind: str, model: Path) -> Any:
    from replaybench.backends.base import BackendOptions

    options = BackendOptions(model=model, threads=1)
    if kind == 'seg':
        from replaybench.backends.onnx_seg import OnnxSegBackend

        backend: Any = OnnxSegBackend(options)
    else:
        from replaybench.backends.onnx_cpu import OnnxCpuBackend

        backend = OnnxCpuBackend(options)
    backend.open()
    return backend


def _latency(backends: Sequence[Any], frames: Sequence[Frame], repeats: int) -> dict[str, Any]:
    """ms per frame of each backend's ``detect``, interleaved rounds; INT8/FP32 per round."""

    def sampler(name: str, backend: Any) -> Sampler:
        def sample() -> float:
            start = time.perf_counter()
            for frame in frames:
                backend.detect(frame)
            return (time.perf_counter() - start) * 1e3 / len(frames)

        return Sampler(name, 'ms', sample, len(frames))

    fp32, int8 = interleaved([sampler('fp32', backends[0]), sampler('int8', backends[1])], repeats)
    ratios = [b / a for a, b in zip(fp32.values, int8.values, strict=True)]
    return {
        'fp32_ms': fp32.median,
        'int8_ms': int8.median,
        'ratio': float(np.median(ratios)),
        'ratio_min': min(ratios),
        'ratio_max': max(ratios),
        'repeats': repeats,
        'frames': len(frames),
    }


def _bootstrap(
    n: int, score: Callable[[Sequence[int]], float], seed: int = 0
) -> tuple[float, float]:
    rng = np.random.default_rng(seed)
    draws = [score(rng.integers(0, n, n).tolist()) for _ in range(BOOTSTRAP)]
    return float(np.percentile(draws, 2.5)), float(np.percentile(draws, 97.5))


def _detections(backend: Any, frames: Sequence[Frame]) -> list[tuple[Any, ...]]:
    return [tuple(backend.detect(f).detections) for f in frames]


def _agreement(a: Sequence[Sequence[Any]], b: Sequence[Sequence[Any]]) -> dict[str, Any]:
    from replaybench.results.agreement import agreement

    keyed_a = {(0, i): list(d) for i, d in enumerate(a)}
    keyed_b = {(0, i): list(d) for i, d in enumerate(b)}
    found = agreement(keyed_a, keyed_b, backend_a='fp32', backend_b='int8', topic='')
    return {
        'boxes_fp32': found.n_a,
        'boxes_int8': found.n_b,
        'matched_frac_fp32': found.matched_frac_a,
        'matched_frac_int8': found.matched_frac_b,
        'mean_iou': found.mean_iou,
    }


def _quantize(model: Path, bag: Path, out: Path, **kw: Any) -> dict[str, Any]:
    from replaybench.app.quantize import QuantizeSettings, quantize_model

    start = time.perf_counter()
    outcome = quantize_model(QuantizeSettings(model=model, bag=bag, out=out, **kw))
    record = dict(outcome.provenance)
    return {
        'seconds': time.perf_counter() - start,
        'frames': record['frames'],
        'excluded': len(record['excluded']),
        'opset': [record['opset_from'], record['opset_to']],
        'method': record['method'],
    }


def _detector_row(
    name: str,
    model: Path,
    int8: Path,
    frames: Sequence[Frame],
    truth: dict[int, Any] | None,
    repeats: int,
) -> dict[str, Any]:
    from replaybench.results.accuracy import evaluate

    fp32_b, int8_b = _backend('det', model), _backend('det', int8)
    try:
        latency = _latency((fp32_b, int8_b), frames, repeats)
        a, b = _detections(fp32_b, frames), _detections(int8_b, frames)
    finally:
        fp32_b.close()
        int8_b.close()
    row: dict[str, Any] = {'model': name, 'latency': latency, 'agreement': _agreement(a, b)}
    if truth is not None:
        gts = [truth[f.stamp_ns] for f in frames]

        def score(sel: Sequence[int], dets: Sequence[Sequence[Any]]) -> float:
            gt = {k: list(gts[i]) for k, i in enumerate(sel)}
            found = {k: list(dets[i]) for k, i in enumerate(sel)}
            return evaluate(gt, found).map50

        full = list(range(len(frames)))
        fp32_map, int8_map = score(full, a), score(full, b)
        low, high = _bootstrap(len(frames), lambda s: score(s, b) - score(s, a))
        row['accuracy'] = {
            'metric': 'mAP@0.5',
            'fp32': fp32_map,
            'int8': int8_map,
            'change': int8_map - fp32_map,
            'ci95': [low, high],
        }
    return row


def _miou(pairs: Sequence[tuple[Any, Any]], classes: int) -> float:
    inter = np.zeros(classes)
    union = np.zeros(classes)
    for pred, gt in pairs:
        for c in range(1, classes):
            p, g = pred == c, gt == c
            inter[c] += np.count_nonzero(p & g)
            union[c] += np.count_nonzero(p | g)
    present = union[1:] > 0
    return float((inter[1:][present] / union[1:][present]).mean())


def _seg_row(
    name: str,
    model: Path,
    int8: Path,
    frames: Sequence[Frame],
    truth: dict[int, Any] | None,
    repeats: int,
) -> dict[str, Any]:
    fp32_b, int8_b = _backend('seg', model), _backend('seg', int8)
    try:
        latency = _latency((fp32_b, int8_b), frames, repeats)
        a = [fp32_b.detect(f).mask.labels for f in frames]
        b = [int8_b.detect(f).mask.labels for f in frames]
    finally:
        fp32_b.close()
        int8_b.close()
    same = [float(np.mean(x == y)) for x, y in zip(a, b, strict=True)]
    row: dict[str, Any] = {
        'model': name,
        'latency': latency,
        'agreement': {'mask_pixels_equal': float(np.mean(same)), 'worst_frame': min(same)},
    }
    if truth is not None:
        gts = [truth[f.stamp_ns] for f in frames]

        def score(sel: Sequence[int], preds: Sequence[Any]) -> float:
            return _miou([(preds[i], gts[i]) for i in sel], 5)

        full = list(range(len(frames)))
        fp32_m, int8_m = score(full, a), score(full, b)
        low, high = _bootstrap(len(frames), lambda s: score(s, b) - score(s, a))
        row['accuracy'] = {
            'metric': 'mIoU',
            'fp32': fp32_m,
            'int8': int8_m,
            'change': int8_m - fp32_m,
            'ci95': [low, high],
        }
    return row


def _photo_bag(path: Path, images: Sequence[Path]) -> Path:
    """The photos (any size) as one rgb8 Image topic, 1/30 s apart."""
    import cv2

    from replaybench.fixtures.writer import FixtureMessage, stamp_ns, write_ros2_mcap
    from replaybench.msgs import IMAGE, serialize_image

    messages = []
    for i, image in enumerate(images):
        bgr = cv2.imread(str(image), cv2.IMREAD_COLOR)
        if bgr is None:
            msg = f'cannot read {image}'
            raise OSError(msg)
        rgb = np.ascontiguousarray(bgr[:, :, ::-1])
        data = serialize_image(stamp_ns(i), 'camera', rgb, 'rgb8')
        messages.append(FixtureMessage(stamp_ns(i), '/camera/image_raw', IMAGE, data))
    return write_ros2_mcap(path, messages)


def _table(rows: Sequence[dict[str, Any]]) -> str:
    lines = [
        (
            '| model | INT8 / FP32 latency | FP32 ms | INT8 ms | accuracy change (95 % CI) | '
            'agreement with FP32 |'
        ),
        '|---|---|---|---|---|---|',
    ]
    for row in rows:
        lat = row['latency']
        acc = row.get('accuracy')
        change = (
            f'{acc["metric"]} {acc["fp32"]:.4f} -> {acc["int8"]:.4f}: {acc["change"]:+.4f} '
            f'[{acc["ci95"][0]:+.4f}, {acc["ci95"][1]:+.4f}]'
            if acc
            else 'n/a (no labels)'
        )
        agree = row['agreement']
        if 'mean_abs_disparity_diff_px' in agree:
            shown = f'disparity {agree["mean_abs_disparity_diff_px"]:.3f} px from FP32 (mean)'
        elif 'mask_pixels_equal' in agree:
            shown = f'{agree["mask_pixels_equal"] * 100:.2f} % of mask pixels equal'
        else:
            frac = agree['matched_frac_fp32']
            iou = agree['mean_iou']
            shown = (
                f'{frac * 100:.1f} % of {agree["boxes_fp32"]} FP32 boxes matched '
                f'({agree["boxes_int8"]} INT8), mean IoU {iou:.3f}'
                if frac is not None and iou is not None
                else f'{agree["boxes_fp32"]} FP32 / {agree["boxes_int8"]} INT8 boxes, none matched'
            )
        lines.append(
            f'| {row["model"]} | {lat["ratio"]:.2f} ({lat["ratio_min"]:.2f}-'
            f'{lat["ratio_max"]:.2f}) | {lat["fp32_ms"]:.2f} | {lat["int8_ms"]:.2f} | '
            f'{change} | {shown} |'
        )
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Measure every row; print the Markdown table; write the figures as JSON to --out."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--out', type=Path, default=None)
    parser.add_argument('--only', default='', help='comma-separated row keys')
    args = parser.parse_args(argv)
    import cv2

    cv2.setNumThreads(1)
    only = set(filter(None, args.only.split(',')))
    models = REPO / 'replaybench' / 'models'
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix='replaybench-quantize-table-') as tmp:
        work = Path(tmp)
        ci = REPO / 'fixtures' / 'bags' / 'ci.mcap'
        held = _frames(ci, start_s=5.0)  # ci.mcap: 300 frames, 10 s; calibrated on 0..5 s
        if not only or 'detector' in only:
            for exclude, label in ((None, 'default: head in float'), ((), '--exclude none')):
                out = work / f'blobs-{len(exclude or ())}.int8.onnx'
                q = _quantize(
                    models / 'blobs.onnx', ci, out, holdout=((5.0, None),), exclude=exclude
                )
                row = _detector_row(
                    f'bundled detector blobs.onnx ({label})',
                    models / 'blobs.onnx',
                    out,
                    held,
                    _truth(ci),
                    args.repeats,
                )
                row['quantize'] = q
                rows.append(row)
                print(_table(rows[-1:]), file=sys.stderr)
        seg_bag = work / 'masks' / 'rgb8_raw.mcap'
        if not only or {'segmenter', 'unet'} & only:
            from replaybench.fixtures.writer import write_mcap

            seg_bag.parent.mkdir()
            write_mcap(seg_bag, 60, masks=True)  # the fixture scene; calibrated on 0..1 s
            seg_held = _frames(seg_bag, start_s=1.0)
        if not only or 'segmenter' in only:
            out = work / 'seg.int8.onnx'
            q = _quantize(models / 'blobs_seg.onnx', seg_bag, out, holdout=((1.0, None),))
            row = _seg_row(
                'bundled segmenter blobs_seg.onnx',
                models / 'blobs_seg.onnx',
                out,
                seg_held,
                _masks(seg_bag),
                args.repeats,
            )
            row['quantize'] = q
            rows.append(row)
            print(_table(rows[-1:]), file=sys.stderr)
        if not only or 'unet' in only:
            from benchmarks.bench_segmentation import _unet_model

            unet = _unet_model(work / 'unet.onnx')
            if unet is not None:
                out = work / 'unet.int8.onnx'
                q = _quantize(
                    unet, seg_bag, out, holdout=((1.0, None),), backend='onnx-seg', frames=30
                )
                row = _seg_row(
                    '384x384 encoder-decoder of item s (random weights)',
                    unet,
                    out,
                    seg_held,
                    None,
                    args.repeats,
                )
                row['quantize'] = q
                rows.append(row)
                print(_table(rows[-1:]), file=sys.stderr)
        if not only or 'stereo' in only:
            rows.append(_stereo_row(work, args.repeats))
            print(_table(rows[-1:]), file=sys.stderr)
        yolox = SHARED / 'models' / 'yolox_nano.onnx'
        if (not only or 'yolox' in only) and yolox.is_file():
            euroc = sorted((SHARED / 'euroc_micro' / 'cam0' / 'data').glob('*.png'))
            tags = sorted((SHARED / 'tags_duckietown').glob('*.png'))
            photos = _photo_bag(work / 'photos.mcap', [*euroc, *tags])
            astronaut = _photo_bag(work / 'astronaut.mcap', [SHARED / 'images' / 'astronaut.png'])
            n_euroc = len(euroc)
            # calibrated on the EuRoC frames (the first n/30 s), held out: the tag photos
            split = (n_euroc - 0.5) / 30
            held_photos = _frames(photos, start_s=split)
            one = _frames(astronaut)
            for method in ('minmax', 'percentile'):
                out = work / f'yolox.{method}.int8.onnx'
                q = _quantize(yolox, photos, out, holdout=((split, None),), method=method)
                row = _detector_row(
                    f'YOLOX-Nano 416x416 ({method}), held-out real photos',
                    yolox,
                    out,
                    held_photos,
                    None,
                    args.repeats,
                )
                row['quantize'] = q
                rows.append(row)
                row = _detector_row(
                    f'YOLOX-Nano ({method}), astronaut.png',
                    yolox,
                    out,
                    one * 20,
                    None,
                    args.repeats,
                )
                row['agreement'] = _agreement(*_astronaut(yolox, out, one))
                row['quantize'] = q
                rows.append(row)
                print(_table(rows[-2:]), file=sys.stderr)
    print(_table(rows))
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=2, sort_keys=True) + '\n', encoding='utf-8')
    return 0


def _stereo_row(work: Path, repeats: int) -> dict[str, Any]:
    """The bundled stereo model on the stereo fixture: calibrated on its first 2 s (20 pairs),
    compared on the other 20; agreement: the mean absolute disparity difference."""
    from replaybench.backends.base import BackendOptions
    from replaybench.backends.onnx_stereo import OnnxStereoBackend
    from replaybench.detector.calibration import calibration_pairs
    from replaybench.fixtures.stereo import write_stereo_mcap
    from replaybench.types import FrameSet

    bag = write_stereo_mcap(work / 'stereo.mcap', frames=40)
    topics = ('/stereo/left/image_rect', '/stereo/right/image_rect')
    model = REPO / 'replaybench' / 'models' / 'stereo_small.onnx'
    out = work / 'stereo.int8.onnx'
    q = _quantize(model, bag, out, frames=20, topics=topics, holdout=((2.0, None),))
    flat = calibration_pairs(bag, 40, topics).frames
    sets = [FrameSet(frames=(flat[i], flat[i + 1])) for i in range(40, len(flat), 2)]
    backends = []
    for path in (model, out):
        backend = OnnxStereoBackend(BackendOptions(model=path, threads=1))
        backend.open()
        backends.append(backend)
    try:
        latency = _latency(backends, sets, repeats)  # type: ignore[arg-type]
        a, b = ([np.asarray(x.detect(s).output.disparity) for s in sets] for x in backends)
    finally:
        for backend in backends:
            backend.close()
    diff = [float(np.nanmean(np.abs(x - y))) for x, y in zip(a, b, strict=True)]
    return {
        'model': 'bundled stereo_small.onnx (320x240 pairs)',
        'latency': latency,
        'agreement': {'mean_abs_disparity_diff_px': float(np.mean(diff))},
        'quantize': q,
    }


def _astronaut(yolox: Path, int8: Path, frames: Sequence[Frame]) -> tuple[Any, Any]:
    fp32_b, int8_b = _backend('det', yolox), _backend('det', int8)
    try:
        return _detections(fp32_b, frames), _detections(int8_b, frames)
    finally:
        fp32_b.close()
        int8_b.close()


if __name__ == '__main__':
    sys.exit(main())
