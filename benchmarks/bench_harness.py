"""Item b: the cost of the harness, i.e. the ``null`` backend through ``run_benchmark``.

Throughput is the run's own steady-state figure (``Summary.throughput_fps``: measured frames
over the time they took, warm-up frames left out), so the run's fixed costs (opening the bag,
its sha256, writing the run folder) are not in it; they are reported as the pass's wall time.
The baseline is reading-only throughput in the same steady state: an opened source, every
frame decoded and one pixel read.
"""

from __future__ import annotations

import time
from functools import partial
from typing import TYPE_CHECKING, Any

from benchmarks.bench_reading import decode_all
from benchmarks.core import (
    ItemResult,
    Measurement,
    Sampler,
    extra_ms,
    interleaved,
    per_second,
    ratio,
)

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from benchmarks.core import Check, Context
    from benchmarks.data import Bag
    from replaybench.sources import Source

__all__ = [
    'BAGS',
    'ITEM',
    'TARGET',
    'ReplayPass',
    'measure_with_reading',
    'replay',
    'run',
    'runner_supports',
    'steady_read_sampler',
]

ITEM = 'b'
#: Bags of the suite this item reads.
BAGS: tuple[str, ...] = ('raw', 'zstd')

TARGET = 0.9


class ReplayPass:
    """Samples ``run_benchmark`` throughput; keeps each run's wall and CPU time as well.

    ``overrides`` are further ``RunConfig`` fields (e.g. ``prefetch=0``).
    """

    def __init__(self, bag: Bag, backend: str, out: Path, **overrides: Any) -> None:
        self.bag = bag
        self.backend = backend
        self.out = out
        self.overrides = overrides
        extra = ''.join(f', {k}={v}' for k, v in overrides.items())
        self.label = f'{backend}, {bag.spec.name}{extra}'
        self.walls: list[float] = []
        self.cores: list[float] = []
        self.records: list[float] = []

    def __call__(self) -> float:
        fps, wall, cpu, record_s = replay(self.bag.path, self.backend, self.out, **self.overrides)
        self.walls.append(wall)
        self.cores.append(cpu / wall)
        self.records.append(record_s * 1e3 / self.bag.spec.frames)
        return fps

    def sampler(self) -> Sampler:
        return Sampler(
            f'run_benchmark[{self.label}]',
            'frames/s',
            self,
            self.bag.spec.frames,
            'Summary.throughput_fps (steady state, warm-up frames excluded)',
        )

    def extras(self, repeats: int) -> list[Measurement]:
        """Wall time and CPU use of the last ``repeats`` runs (the kept rounds)."""
        frames = self.bag.spec.frames
        return [
            Measurement(
                f'run_benchmark wall[{self.label}]',
                's',
                tuple(self.walls[-repeats:]),
                frames,
                'whole run: open, sha256, every frame, run folder',
            ),
            Measurement(
                f'run_benchmark cpu[{self.label}]',
                'cores',
                tuple(self.cores[-repeats:]),
                frames,
                'process CPU time / wall time of the whole run',
            ),
            Measurement(
                f'record keeping per frame[{self.label}]',
                'ms',
                tuple(self.records[-repeats:]),
                frames,
                'records, frames.csv rows, detections messages, made after the pass (run.json '
                'backends[0].record_s / frames); in the wall time, not in the throughput',
            ),
        ]


def runner_supports(name: str) -> bool:
    """Whether ``RunConfig`` has the field ``name``."""
    from dataclasses import fields

    from replaybench.replay.runner import RunConfig

    return any(f.name == name for f in fields(RunConfig))


def replay(
    path: Path, backend: str, out: Path, **overrides: Any
) -> tuple[float, float, float, float]:
    """One ``run_benchmark`` at max rate, one thread.

    Returns (steady-state frames/s, wall s, CPU s, record keeping s).
    """
    from replaybench.replay.runner import RunConfig, run_benchmark

    config = RunConfig(
        inputs=[path],
        backends=[backend],
        out_dir=out,
        force=True,
        threads=1,
        report=False,
        **overrides,
    )
    start, cpu = time.perf_counter(), time.process_time()
    outcome = run_benchmark(config)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    (summary,) = outcome.summaries
    record_s = outcome.run.backends[0].record_s
    if outcome.status != 'complete' or summary.throughput_fps is None or record_s is None:
        msg = f'run of {backend} on {path.name}: status {outcome.status}, no throughput'
        raise RuntimeError(msg)
    return summary.throughput_fps, wall, cpu, record_s


def steady_read_sampler(source: Source, bag: Bag) -> Sampler:
    """Frames/s of decoding every frame of an already opened source (reading-only stage)."""
    return Sampler(
        f'read+decode steady[{bag.spec.name}]',
        'frames/s',
        per_second(partial(decode_all, source)),
        bag.spec.frames,
        'source opened beforehand',
    )


def measure_with_reading(
    ctx: Context, bag: Bag, samplers: Sequence[Sampler]
) -> tuple[list[Measurement], Measurement]:
    """``samplers`` in rounds with the bag's reading-only stage: (their measurements, reading)."""
    from replaybench.sources import open_source

    with open_source(bag.path) as source:
        *measured, reading = interleaved(
            [*samplers, steady_read_sampler(source, bag)], ctx.settings.repeats
        )
    return measured, reading


def _with_record_keeping(fps: Measurement, records: Measurement) -> Measurement:
    """Frames/s had each frame's record keeping (ms) run inside the replay, round by round."""
    values = tuple(
        1.0 / (1.0 / f + ms / 1e3) for f, ms in zip(fps.values, records.values, strict=True)
    )
    return Measurement(
        fps.name.replace('run_benchmark[', 'run_benchmark + record keeping['),
        'frames/s',
        values,
        fps.frames,
        '1 / (1 / steady-state frames/s + record keeping s per frame)',
    )


def run(ctx: Context) -> ItemResult:
    measurements: list[Measurement] = []
    checks: list[Check] = []
    for name in ('raw', 'zstd'):
        bag = ctx.bags[name]
        runs = ReplayPass(bag, 'null', ctx.tmp / f'run-null-{name}')
        (fps,), reading = measure_with_reading(ctx, bag, [runs.sampler()])
        extras = runs.extras(ctx.settings.repeats)
        with_records = _with_record_keeping(fps, extras[-1])
        measurements += [reading, fps, *extras, with_records]
        checks += [
            ratio(ITEM, f'null run_benchmark vs reading only [{name}]', fps, reading, TARGET),
            extra_ms(ITEM, f'harness cost per frame [{name}]', fps, reading),
            ratio(
                ITEM,
                f'null run_benchmark with its record keeping vs reading only [{name}]',
                with_records,
                reading,
                None,
                note='record keeping runs after the pass, outside the throughput; told for scale',
            ),
        ]
    notes = [
        (
            'run_benchmark(report=False, rate max, threads=1) into a temp folder; throughput from '
            'the run summary (steady state) because the fixed costs (sha256 of the bag above all) '
            'dominate a run this short; the wall time of each run is listed as well.'
        ),
    ]
    return ItemResult(ITEM, 'Harness overhead: null backend', measurements, checks, notes)
