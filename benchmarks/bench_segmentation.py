"""Item s: segmentation backends against their baselines.

``hsv-seg`` against the straightforward per-class OpenCV port of the same masks
(``benchmarks/naive_hsv_seg.py``) on the same BGR scene frames, with the masks compared pixel
for pixel (target: at least 2x the frames per second).

``onnx-seg``: ``detect`` (preprocess into the input tensor, ``session.run``, argmax and the map
back to the frame) against a bare ``session.run`` on a tensor prepared beforehand, the same
session, one intra-op thread, for two models:

* an encoder-decoder of the size robot segmenters run (``_unet_model``: seven 3x3
  convolutions, 384x384 input, 4 classes as [1, C, H, W] scores; random weights, since only its
  cost matters here), on 640x480 scene frames: the harness's overhead at a realistic inference
  cost (target: at most 1.10x the time per frame);
* the bundled ``blobs_seg.onnx`` (320x240 input, 11.6 k parameters) on 320x240 frames: a figure
  without a target, because its inference (a few ms) is of the order of the per-frame argmax
  and map back, which any segmentation pipeline has to do.

Mask bytes: the outputs.mcap bytes one 1920x1080 label mask costs as written
(``DetectionsWriter``: zstd chunks of ``CHUNK_SIZE``), for the mono8 mask alone and with the
rgb8 colour copy of ``--annotations``: the file with the scene frames' masks minus the file
without, per frame (a figure, no target).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from benchmarks.bench_hsv import bgr_frame
from benchmarks.core import Check, ItemResult, Sampler, interleaved, per_second, ratio

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from benchmarks.core import Context, Measurement

__all__ = ['BAGS', 'HSV_TARGET', 'ITEM', 'ONNX_TARGET', 'run']

ITEM = 's'
#: Bags of the suite this item reads.
BAGS: tuple[str, ...] = ()

HSV_TARGET = 2.0
ONNX_TARGET = 1.10


def _sampler(name: str, work: Callable[[int], object], count: int) -> Sampler:
    def frames() -> int:
        for i in range(count):
            work(i)
        return count

    return Sampler(name, 'frames/s', per_second(frames), count)


def _hsv_checks(
    ctx: Context, size: tuple[int, int], measurements: list[Measurement]
) -> list[Check]:
    import numpy as np

    from benchmarks.naive_hsv_seg import naive_segment
    from replaybench.backends.hsv_seg import HsvSegBackend

    images = ctx.scene_frames(size)
    frames = [bgr_frame(image, i) for i, image in enumerate(images)]
    backend = HsvSegBackend()
    backend.open()
    try:
        label = f'{size[0]}x{size[1]}'
        n = len(frames)
        fast, naive = interleaved(
            [
                _sampler(f'hsv-seg detect[{label}]', lambda i: backend.detect(frames[i]), n),
                _sampler(f'naive_segment[{label}]', lambda i: naive_segment(images[i]), n),
            ],
            ctx.settings.repeats,
        )
        measurements += [fast, naive]
        same = 0
        for frame, image in zip(frames, images, strict=True):
            mask = backend.detect(frame).mask
            same += mask is not None and bool(np.array_equal(mask.labels, naive_segment(image)))
    finally:
        backend.close()
    share = same / len(frames)
    return [
        ratio(ITEM, f'hsv-seg vs naive per-class port [{label}]', fast, naive, HSV_TARGET),
        Check(
            ITEM,
            f'identical label masks [{label}]',
            share,
            share,
            share,
            'of frames',
            1.0,
            basis=f'{len(frames)} frames, every pixel',
        ),
    ]


def _unet_model(path: Path) -> Path | None:
    """A U-Net-sized segmentation model (ONNX, [1, 3, 384, 384] -> [1, 4, 384, 384] scores),
    exported with torch; None where torch is not installed."""
    try:
        import torch
    except ImportError:
        return None
    from torch import nn

    torch.manual_seed(0)

    def block(cin: int, cout: int, stride: int = 1) -> list[nn.Module]:
        return [nn.Conv2d(cin, cout, 3, stride, 1), nn.ReLU()]

    net = nn.Sequential(
        *block(3, 24, 2),
        *block(24, 48, 2),
        *block(48, 96, 2),
        *block(96, 96),
        nn.Upsample(scale_factor=2),
        *block(96, 48),
        nn.Upsample(scale_factor=2),
        *block(48, 24),
        nn.Upsample(scale_factor=2),
        nn.Conv2d(24, 4, 3, 1, 1),
    ).eval()
    torch.onnx.export(
        net,
        (torch.zeros(1, 3, 384, 384),),
        str(path),
        input_names=['images'],
        output_names=['logits'],
        opset_version=17,
        dynamo=False,
    )
    return path


def _onnx_ratio(
    ctx: Context,
    label: str,
    size: tuple[int, int],
    model: Path | None,
    measurements: list[Measurement],
) -> tuple[Measurement, Measurement]:
    from replaybench.backends.base import BackendOptions
    from replaybench.backends.onnx_seg import OnnxSegBackend

    images = ctx.scene_frames(size)
    frames = [bgr_frame(image, i) for i, image in enumerate(images)]
    backend = OnnxSegBackend(BackendOptions(threads=1, model=model))
    backend.open()
    try:
        session, names, feed = backend._session, backend._names, backend._feed
        backend.detect(frames[0])  # the feed holds a real frame
        n = len(frames)

        def bare(_: int) -> object:
            return session.run(names, feed)

        full, alone = interleaved(
            [
                _ms_sampler(f'onnx-seg detect[{label}]', lambda i: backend.detect(frames[i]), n),
                _ms_sampler(f'bare session.run[{label}]', bare, n),
            ],
            ctx.settings.repeats,
        )
    finally:
        backend.close()
    measurements += [full, alone]
    return full, alone


def _onnx_checks(ctx: Context, measurements: list[Measurement]) -> list[Check]:
    note = 'ms per frame: preprocess + inference + argmax and map back, over inference'
    checks = []
    model = _unet_model(ctx.tmp / 'unet_seg.onnx')
    if model is not None:
        label = f'384x384 encoder-decoder, {ctx.settings.small[0]}x{ctx.settings.small[1]}'
        full, alone = _onnx_ratio(ctx, label, ctx.settings.small, model, measurements)
        checks.append(
            ratio(
                ITEM,
                f'onnx-seg detect vs bare session.run [{label}]',
                full,
                alone,
                ONNX_TARGET,
                op='<=',
                note=note,
            )
        )
    label = 'bundled blobs_seg, 320x240'
    full, alone = _onnx_ratio(ctx, label, (320, 240), None, measurements)
    checks.append(
        ratio(
            ITEM,
            f'onnx-seg detect vs bare session.run [{label}]',
            full,
            alone,
            None,
            op='<=',
            note=note + '; no target: a few-ms model, of the order of the argmax',
        )
    )
    return checks


def _ms_sampler(name: str, work: Callable[[int], object], count: int) -> Sampler:
    def sample() -> float:
        start = time.perf_counter()
        for i in range(count):
            work(i)
        return (time.perf_counter() - start) / count * 1e3

    return Sampler(name, 'ms/frame', sample, count)


def _mcap_bytes(ctx: Context, *, annotations: bool) -> tuple[float, int]:
    """outputs.mcap bytes per 1080p mask, and the frames written."""
    from replaybench.backends.hsv_seg import HsvSegBackend
    from replaybench.sinks.mcap_writer import DetectionsWriter
    from replaybench.tasks.segmentation.sink import add_mask

    images = ctx.scene_frames(ctx.settings.big)
    backend = HsvSegBackend()
    masks = []
    for i, image in enumerate(images):
        mask = backend.detect(bgr_frame(image, i)).mask
        assert mask is not None
        masks.append(mask.labels)
    sizes = []
    for count in (0, len(masks)):
        path = ctx.tmp / f'masks_{annotations}_{count}.mcap'
        with DetectionsWriter(path, annotations=annotations) as writer:
            for i, labels in enumerate(masks[:count]):
                add_mask(writer, 'hsv-seg', '/camera/image_raw', i, i, 'cam', labels)
        sizes.append(path.stat().st_size)
        path.unlink()
    return (sizes[1] - sizes[0]) / len(masks), len(masks)


def _byte_checks(ctx: Context) -> list[Check]:
    checks = []
    for coloured in (False, True):
        per_frame, frames = _mcap_bytes(ctx, annotations=coloured)
        kind = 'mono8 + rgb8 (--annotations)' if coloured else 'mono8'
        big = ctx.settings.big
        checks.append(
            Check(
                ITEM,
                f'detections.mcap bytes per {big[0]}x{big[1]} mask [{kind}]',
                per_frame,
                per_frame,
                per_frame,
                'bytes/frame',
                None,
                basis=f'{frames} hsv-seg masks of scene frames, zstd chunks',
                note=f'raw: {big[0] * big[1] * (4 if coloured else 1)} bytes/frame',
            )
        )
    return checks


def run(ctx: Context) -> ItemResult:
    measurements: list[Measurement] = []
    checks: list[Check] = []
    for size in (ctx.settings.big, ctx.settings.small):
        checks += _hsv_checks(ctx, size, measurements)
    checks += _onnx_checks(ctx, measurements)
    checks += _byte_checks(ctx)
    notes = [
        (
            f'{ctx.settings.pool} distinct scene frames (replaybench.fixtures.scene) per size, '
            'BGR; one cv2 thread; hsv-seg and the naive port use the default hsv configuration.'
        ),
    ]
    return ItemResult(ITEM, 'segmentation backends vs baselines', measurements, checks, notes)
