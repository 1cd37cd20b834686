"""Measurements, checks against targets, repeat-and-median timing and fixed thread counts."""

from __future__ import annotations

import gc
import os
import statistics
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    import numpy as np
    import numpy.typing as npt

    from benchmarks.data import Bag

__all__ = [
    'THREAD_ENV',
    'Check',
    'Context',
    'ItemResult',
    'Measurement',
    'Sampler',
    'Settings',
    'at_most',
    'extra_ms',
    'fix_threads',
    'interleaved',
    'per_second',
    'pin_thread_env',
    'ratio',
    'run_alone',
]

#: Thread-pool variables pinned to 1 before numpy / OpenCV load.
THREAD_ENV = ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')

Op = Literal['>=', '<=']


def pin_thread_env() -> None:
    """Set the thread-pool variables to 1; call before numpy or OpenCV is imported."""
    for name in THREAD_ENV:
        os.environ[name] = '1'


def fix_threads() -> dict[str, Any]:
    """One OpenCV thread and one thread per BLAS / OpenMP pool; returns what is in effect."""
    import cv2

    pin_thread_env()
    cv2.setNumThreads(1)
    return {
        'cv2.setNumThreads': 1,
        'cv2.getNumThreads': int(cv2.getNumThreads()),
        **{name: os.environ[name] for name in THREAD_ENV},
    }


class Measurement(NamedTuple):
    """One quantity measured ``len(values)`` times (after discarded warm-up repeats)."""

    name: str
    unit: str
    values: tuple[float, ...]
    frames: int | None = None
    note: str = ''

    @property
    def median(self) -> float:
        return float(statistics.median(self.values))

    @property
    def min(self) -> float:
        return min(self.values)

    @property
    def max(self) -> float:
        return max(self.values)

    def as_dict(self) -> dict[str, Any]:
        return {
            'name': self.name,
            'unit': self.unit,
            'frames': self.frames,
            'repeats': list(self.values),
            'median': self.median,
            'min': self.min,
            'max': self.max,
            'note': self.note,
        }


class Check(NamedTuple):
    """A figure next to its target; ``low`` / ``high`` bound it over the repeats."""

    item: str
    name: str
    value: float
    low: float
    high: float
    unit: str
    target: float | None
    op: Op = '>='
    basis: str = ''
    note: str = ''

    @property
    def passed(self) -> bool | None:
        """None for figures reported without a target."""
        if self.target is None:
            return None
        if self.op == '>=':
            return self.value >= self.target
        return self.value <= self.target

    def as_dict(self) -> dict[str, Any]:
        return {**self._asdict(), 'passed': self.passed}


def ratio(
    item: str,
    name: str,
    measured: Measurement,
    baseline: Measurement,
    target: float | None,
    *,
    op: Op = '>=',
    note: str = '',
) -> Check:
    """``measured`` / ``baseline`` from the medians.

    The spread is that of the per-round ratios when both were measured in the same rounds
    (``interleaved``), else the extremes paired (min / max .. max / min).
    """
    if len(measured.values) == len(baseline.values):
        rounds = [m / b for m, b in zip(measured.values, baseline.values, strict=True)]
        low, high = min(rounds), max(rounds)
    else:
        low, high = measured.min / baseline.max, measured.max / baseline.min
    return Check(
        item,
        name,
        measured.median / baseline.median,
        low,
        high,
        'x',
        target,
        op,
        f'{measured.name} / {baseline.name}',
        note,
    )


def extra_ms(item: str, name: str, slower: Measurement, faster: Measurement) -> Check:
    """Milliseconds per frame that ``slower`` spends beyond ``faster`` (both in frames/s).

    Reported without a target; the spread is that of the per-round differences.
    """

    def cost(s: float, f: float) -> float:
        return 1e3 / s - 1e3 / f

    if len(slower.values) == len(faster.values):
        # paired rounds: the median of their differences, inside their spread (the difference
        # of the two medians need not be)
        rounds = [cost(s, f) for s, f in zip(slower.values, faster.values, strict=True)]
        value = statistics.median(rounds)
    else:
        rounds = [cost(slower.max, faster.min), cost(slower.min, faster.max)]
        value = cost(slower.median, faster.median)
    return Check(
        item,
        name,
        value,
        min(rounds),
        max(rounds),
        'ms',
        None,
        '<=',
        f'1000 / {slower.name} - 1000 / {faster.name}',
    )


def at_most(item: str, name: str, measured: Measurement, target: float, note: str = '') -> Check:
    """The median of ``measured`` against an upper bound in its own unit."""
    return Check(
        item,
        name,
        measured.median,
        measured.min,
        measured.max,
        measured.unit,
        target,
        '<=',
        measured.name,
        note,
    )


class Sampler(NamedTuple):
    """How to take one value of a measurement."""

    name: str
    unit: str
    sample: Callable[[], float]
    frames: int | None = None
    note: str = ''


def interleaved(samplers: Sequence[Sampler], repeats: int, *, warmup: int = 1) -> list[Measurement]:
    """Rounds of one call of each sampler in turn: ``warmup`` rounds discarded, ``repeats`` kept.

    Taking a measurement and its baseline in alternation exposes both to the same machine
    state (other processes, thermal state, page cache), so their ratio is steadier than
    that of two back-to-back series.
    """
    values: list[list[float]] = [[] for _ in samplers]
    for n in range(warmup + repeats):
        for sampler, kept in zip(samplers, values, strict=True):
            gc.collect()
            value = sampler.sample()
            if n >= warmup:
                kept.append(value)
    return [
        Measurement(s.name, s.unit, tuple(v), s.frames, s.note)
        for s, v in zip(samplers, values, strict=True)
    ]


def per_second(work: Callable[[], int]) -> Callable[[], float]:
    """A sampler timing ``work`` (which returns how many frames it did): frames per second."""

    def sample() -> float:
        start = time.perf_counter()
        frames = work()
        return frames / (time.perf_counter() - start)

    return sample


@dataclass(frozen=True, slots=True)
class Settings:
    """Sizes and repeat counts of one suite run."""

    quick: bool
    big: tuple[int, int]  #: the "1080p" size
    small: tuple[int, int]  #: the "640x480" size
    raw_frames: int  #: frames of the uncompressed and zstd bags (the ~2 GB bag at 1080p)
    jpeg_frames: int
    memory_small_frames: int  #: frames of the ~200 MB bag
    pool: int  #: distinct scene frames a bag cycles through
    repeats: int  #: kept rounds of each timing (after one warm-up round)
    memory_repeats: int
    min_free_bytes: int  #: free space the memory item needs

    @classmethod
    def full(cls) -> Settings:
        return cls(
            quick=False,
            big=(1920, 1080),
            small=(640, 480),
            raw_frames=330,
            jpeg_frames=150,
            memory_small_frames=33,
            pool=12,
            repeats=5,
            memory_repeats=3,
            min_free_bytes=5 << 30,
        )

    @classmethod
    def tiny(cls) -> Settings:
        return cls(
            quick=True,
            big=(320, 240),
            small=(160, 120),
            raw_frames=30,
            jpeg_frames=30,
            memory_small_frames=3,
            pool=3,
            repeats=2,
            memory_repeats=1,
            min_free_bytes=100 << 20,
        )


@dataclass(slots=True)
class Context:
    """What every item gets: settings, the temp folder and the generated bags."""

    settings: Settings
    tmp: Path
    bags: dict[str, Bag] = field(default_factory=dict)
    free_bytes: int | None = None  #: free space in ``tmp`` before any bag was written
    pools: dict[tuple[int, int], list[npt.NDArray[np.uint8]]] = field(default_factory=dict)

    def scene_frames(self, size: tuple[int, int]) -> list[npt.NDArray[np.uint8]]:
        """``settings.pool`` distinct BGR scene frames of ``size``, rendered once."""
        if size not in self.pools:
            from benchmarks.data import scene_frames

            self.pools[size] = scene_frames(size, self.settings.pool)
        return self.pools[size]


class ItemResult(NamedTuple):
    """One item of the suite: what was measured, the checks, and notes (or why it was skipped)."""

    item: str
    title: str
    measurements: list[Measurement]
    checks: list[Check]
    notes: list[str]
    skipped: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            'item': self.item,
            'title': self.title,
            'skipped': self.skipped,
            'notes': self.notes,
            'measurements': [m.as_dict() for m in self.measurements],
            'checks': [c.as_dict() for c in self.checks],
        }


def run_alone(
    run: Callable[[Context], ItemResult],
    *,
    prog: str,
    description: str,
    out: Path,
    argv: Sequence[str] | None,
    width: int = 45,
) -> int:
    """Run one item outside the suite (``python -m benchmarks.X [--quick] [--repeats N]
    [--out PATH]``): print its figures and write them with the threads, settings, machine and
    command as JSON. Call ``pin_thread_env`` before importing numpy."""
    import argparse
    import dataclasses
    import sys
    import tempfile
    from pathlib import Path

    from replaybench.results.atomic import write_json_atomic
    from replaybench.results.machine import environment

    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument('--quick', action='store_true', help='few frames, two rounds')
    parser.add_argument('--repeats', type=int, default=None, help='rounds kept (default 5)')
    parser.add_argument('--out', type=Path, default=out, help=f'where {out.name} goes')
    args = parser.parse_args(argv)
    settings = Settings.tiny() if args.quick else Settings.full()
    if args.repeats is not None:
        settings = dataclasses.replace(settings, repeats=args.repeats)
    threads = fix_threads()
    name = prog.rsplit('.', 1)[-1].replace('_', '-')
    with tempfile.TemporaryDirectory(prefix=f'replaybench-{name}-') as tmp:
        result = run(Context(settings, Path(tmp), {}))
    if result.skipped:
        print(f'item {result.item} skipped: {result.skipped}')
        return 0
    for m in result.measurements:
        print(f'{m.name:{width}s} median {m.median:8.3f} {m.unit}  ({m.min:.3f} .. {m.max:.3f})')
    for note in result.notes:
        print(note)
    for c in result.checks:
        verdict = {True: 'PASS', False: 'FAIL', None: 'info'}[c.passed]
        unit = c.unit if c.unit in ('x', '') else f' {c.unit}'
        target = '' if c.target is None else f' (target {c.op} {c.target:.2f}{unit})'
        note = f' ({c.note})' if c.note else ''
        print(
            f'{c.name}: {c.value:.3f}{unit} [{c.low:.3f} .. {c.high:.3f}]{target} {verdict}{note}'
        )
    document: dict[str, Any] = {
        'item': result.as_dict(),
        'threads': threads,
        'settings': dataclasses.asdict(settings),
        'environment': environment(),
        'command': [sys.executable, *sys.argv],
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out, document)
    print(f'wrote {args.out}')
    return 0
