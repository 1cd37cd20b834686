"""Item s: segmentation backends against their baselines.

``hsv-seg`` against the straightforward per-class OpenCV port of the same masks
(``benchmarks/naive_hsv_seg.py``) on the same BGR scene frames, with the masks compared pixel
for pixel (target: at least 2x the frames per second).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from benchmarks.bench_hsv import bgr_frame
from benchmarks.core import Check, ItemResult, Sampler, interleaved, per_second, ratio

if TYPE_CHECKING:
    from collections.abc import Callable

    from benchmarks.core import Context, Measurement

__all__ = ['BAGS', 'HSV_TARGET', 'ITEM', 'run']

ITEM = 's'
#: Bags of the suite this item reads.
BAGS: tuple[str, ...] = ()

HSV_TARGET = 2.0


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


def run(ctx: Context) -> ItemResult:
    measurements: list[Measurement] = []
    checks: list[Check] = []
    for size in (ctx.settings.big, ctx.settings.small):
        checks += _hsv_checks(ctx, size, measurements)
    notes = [
        (
            f'{ctx.settings.pool} distinct scene frames (replaybench.fixtures.scene) per size, '
            'BGR; one cv2 thread; hsv-seg and the naive port use the default hsv configuration.'
        ),
    ]
    return ItemResult(ITEM, 'segmentation backends vs baselines', measurements, checks, notes)
