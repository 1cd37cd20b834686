"""Item c: the hsv backend against the naive port of the lab node (benchmarks/naive_hsv.py).

Both run on the same BGR scene frames; their detections are compared frame by frame.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from benchmarks.core import Check, ItemResult, Sampler, interleaved, per_second, ratio

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    import numpy as np
    import numpy.typing as npt

    from benchmarks.core import Context, Measurement
    from replaybench.types import Detection, Frame

__all__ = ['BAGS', 'ITEM', 'TARGET', 'bgr_frame', 'run']

ITEM = 'c'
#: Bags of the suite this item reads.
BAGS: tuple[str, ...] = ()

TARGET = 2.0


def bgr_frame(image: npt.NDArray[np.uint8], seq: int = 0) -> Frame:
    """A backend frame around a BGR image."""
    from replaybench.types import Frame

    return Frame('/camera/image_raw', seq, seq, seq, 'camera_optical_frame', image, 'bgr8', 'bgr8')


def _sampler(name: str, detect: Callable[[int], object], count: int) -> Sampler:
    def work() -> int:
        for i in range(count):
            detect(i)
        return count

    return Sampler(name, 'frames/s', per_second(work), count)


def _agreement(
    fast: Sequence[Sequence[Detection]], naive: Sequence[Sequence[Detection]], label: str
) -> list[Check]:
    """Share of frames with as many detections as the naive port, and with identical ones."""
    pairs = list(zip(fast, naive, strict=True))
    basis = f'{len(pairs)} frames, {sum(len(d) for d in fast)} detections'
    same_count = sum(len(a) == len(b) for a, b in pairs) / len(pairs)
    identical = sum(list(a) == list(b) for a, b in pairs) / len(pairs)
    return [
        Check(
            ITEM,
            f'same detection count [{label}]',
            same_count,
            same_count,
            same_count,
            'of frames',
            1.0,
            basis=basis,
        ),
        Check(
            ITEM,
            f'identical detections [{label}]',
            identical,
            identical,
            identical,
            'of frames',
            None,
            basis=basis,
            note='boxes, scores and order; reported',
        ),
    ]


def _size_checks(
    ctx: Context, size: tuple[int, int], measurements: list[Measurement]
) -> list[Check]:
    from benchmarks.naive_hsv import naive_detect
    from replaybench.backends.hsv import HsvBackend

    images = ctx.scene_frames(size)
    frames = [bgr_frame(image, i) for i, image in enumerate(images)]
    backend = HsvBackend()
    backend.open()
    try:
        label = f'{size[0]}x{size[1]}'
        n = len(frames)
        fast, naive = interleaved(
            [
                _sampler(f'hsv detect[{label}]', lambda i: backend.detect(frames[i]), n),
                _sampler(f'naive_detect[{label}]', lambda i: naive_detect(images[i]), n),
            ],
            ctx.settings.repeats,
        )
        measurements += [fast, naive]
        agreement = _agreement(
            [backend.detect(f).detections for f in frames],
            [naive_detect(im) for im in images],
            label,
        )
    finally:
        backend.close()
    return [ratio(ITEM, f'hsv vs naive [{label}]', fast, naive, TARGET), *agreement]


def run(ctx: Context) -> ItemResult:
    measurements: list[Measurement] = []
    checks: list[Check] = []
    for size in (ctx.settings.big, ctx.settings.small):
        checks += _size_checks(ctx, size, measurements)
    notes = [
        (
            f'{ctx.settings.pool} distinct scene frames (replaybench.fixtures.scene) per size, '
            'BGR; one cv2 thread.'
        ),
    ]
    return ItemResult(ITEM, 'hsv backend vs naive port', measurements, checks, notes)
