"""Item d: ``run_benchmark`` with hsv on a JPEG bag against the slower of its two stages alone.

Stage 1 is reading + decoding the bag (an opened source, every JPEG decoded); stage 2 is
``HsvBackend.detect`` on frames decoded beforehand from the same bag. A pipeline that overlaps
the stages approaches the slower one; a serial one gets the sum of both per-frame times.

Reported beside it: the run with the prefetch thread switched off (``prefetch=0``), and both
stages run at once in two bare threads, which is as much overlap as the machine's cores allow.
"""

from __future__ import annotations

import threading
from itertools import islice
from typing import TYPE_CHECKING

from benchmarks.bench_harness import ReplayPass, measure_with_reading, runner_supports
from benchmarks.bench_reading import read_replaybench
from benchmarks.core import ItemResult, Measurement, Sampler, per_second, ratio

if TYPE_CHECKING:
    from collections.abc import Callable

    from benchmarks.core import Check, Context
    from benchmarks.data import Bag
    from replaybench.types import Frame

__all__ = ['BAGS', 'ITEM', 'TARGET', 'decoded_frames', 'detect_work', 'run', 'two_threads']

ITEM = 'd'
#: Bags of the suite this item reads.
BAGS: tuple[str, ...] = ('jpeg', 'jpeg_small')

TARGET = 0.85


def decoded_frames(bag: Bag, count: int) -> list[Frame]:
    """The first ``count`` frames of ``bag``, decoded (the pool the bag cycles through)."""
    from replaybench.decode import decode_image
    from replaybench.sources import open_source
    from replaybench.types import Frame

    frames = []
    with open_source(bag.path) as source:
        for raw in islice(source.messages(), count):
            d = decode_image(raw)
            frames.append(
                Frame(
                    raw.topic,
                    raw.seq,
                    raw.log_time_ns,
                    d.stamp_ns,
                    d.frame_id,
                    d.image.copy(),
                    d.encoding,
                    d.source_encoding,
                )
            )
    return frames


def detect_work(
    frames: list[Frame], total: int, detect: Callable[[Frame], object]
) -> Callable[[], int]:
    """Stage 2 alone: ``detect`` on ``total`` frames, cycling through ``frames``."""

    def work() -> int:
        for i in range(total):
            detect(frames[i % len(frames)])
        return total

    return work


def two_threads(bag: Bag, stage2: Callable[[], int]) -> Callable[[], int]:
    """Both stages at once, each in its own thread, nothing passed between them.

    What the machine allows any pipeline of these two stages: the ceiling for ``run_benchmark``.
    """

    def work() -> int:
        reader = threading.Thread(target=read_replaybench, args=(bag.path,))
        reader.start()
        try:
            return stage2()
        finally:
            reader.join()

    return work


def _bag_checks(ctx: Context, bag: Bag, measurements: list[Measurement]) -> list[Check]:
    from replaybench.backends.hsv import HsvBackend

    name = bag.spec.name
    n = bag.spec.frames
    passes = [ReplayPass(bag, 'hsv', ctx.tmp / f'run-hsv-{name}')]
    if runner_supports('prefetch'):
        passes.append(ReplayPass(bag, 'hsv', ctx.tmp / f'run-hsv-serial-{name}', prefetch=0))
    frames = decoded_frames(bag, ctx.settings.pool)
    backend = HsvBackend()
    backend.open()
    try:
        stage2 = detect_work(frames, n, backend.detect)
        samplers = [
            Sampler(f'hsv detect[{name}]', 'frames/s', per_second(stage2), n, 'decoded before'),
            Sampler(
                f'two bare threads[{name}]',
                'frames/s',
                per_second(two_threads(bag, stage2)),
                n,
                'read+decode in one thread, hsv detect in another',
            ),
            *(p.sampler() for p in passes),
        ]
        (detect, bare, fps, *serial), read = measure_with_reading(ctx, bag, samplers)
    finally:
        backend.close()
    measurements += [read, detect, bare, fps, *serial]
    measurements += [m for p in passes for m in p.extras(ctx.settings.repeats)]
    slower = min(read, detect, key=lambda m: m.median)
    checks = [
        ratio(
            ITEM,
            f'hsv run_benchmark vs slower stage [{name}]',
            fps,
            slower,
            TARGET,
            note=f'slower stage: {slower.name}',
        ),
        ratio(
            ITEM,
            f'two bare threads vs slower stage [{name}]',
            bare,
            slower,
            None,
            note='the ceiling this machine allows',
        ),
        ratio(ITEM, f'hsv run_benchmark vs two bare threads [{name}]', fps, bare, None),
    ]
    checks += [ratio(ITEM, f'prefetch vs serial run [{name}]', fps, s, None) for s in serial]
    return checks


def run(ctx: Context) -> ItemResult:
    measurements: list[Measurement] = []
    checks: list[Check] = []
    for name in ('jpeg', 'jpeg_small'):
        checks += _bag_checks(ctx, ctx.bags[name], measurements)
    notes = [
        (
            "Pipeline throughput is the run summary's steady-state throughput_fps "
            '(run_benchmark, rate max, threads=1, report=False); the baseline is the slower '
            'of the two stages measured alone, in the same rounds.'
        ),
        (
            'two bare threads: stage 1 and stage 2 at the same time in two threads with nothing '
            'passed between them; its ratio to the slower stage is the ceiling of any pipeline '
            'on this machine.'
        ),
    ]
    return ItemResult(
        ITEM, 'Pipeline: read+decode overlapped with hsv', measurements, checks, notes
    )
