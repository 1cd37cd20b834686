"""Item e: peak memory of ``replaybench run BAG --backend null`` in a subprocess.

The parent samples ``/proc/<pid>/status`` about every 20 ms: ``RssAnon`` is the child's
private anonymous memory (heap, arrays); pages of the memory-mapped bag are file-backed page
cache (``RssFile``) and are not counted. Peak RSS is the kernel's high-water mark ``VmHWM``
(every resident page, mapped file pages included) as last sampled. ``ru_maxrss`` is not used:
it also counts the parent's RSS at fork time.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from typing import TYPE_CHECKING, NamedTuple

from benchmarks.core import ItemResult, Measurement, at_most, ratio

if TYPE_CHECKING:
    from benchmarks.core import Context
    from benchmarks.data import Bag

__all__ = ['BAGS', 'ITEM', 'LIMIT_MIB', 'SAMPLE_INTERVAL_S', 'Peak', 'peak_memory', 'run']

ITEM = 'e'
#: Bags of the suite this item reads.
BAGS: tuple[str, ...] = ('raw', 'memory_small')

LIMIT_MIB = 400.0
GROWTH_LIMIT = 1.10
SAMPLE_INTERVAL_S = 0.02
_MIB = 1 << 20


class Peak(NamedTuple):
    """Peaks of one child process, in bytes, and how many samples were taken."""

    anon: int
    file: int
    rss: int
    samples: int


def _status_bytes(pid: int) -> dict[str, int]:
    """The ``kB`` fields of ``/proc/<pid>/status`` in bytes; empty once the process is gone."""
    try:
        with open(f'/proc/{pid}/status', encoding='ascii') as f:  # noqa: PTH123 - hot loop
            text = f.read()
    except OSError:
        return {}
    fields = {}
    for line in text.splitlines():
        name, _, rest = line.partition(':')
        parts = rest.split()
        if len(parts) == 2 and parts[1] == 'kB':
            fields[name] = int(parts[0]) * 1024
    return fields


def peak_memory(command: list[str], env: dict[str, str]) -> Peak:
    """Run ``command``, sampling its memory until it exits; RuntimeError if it fails."""
    proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    peak = {'RssAnon': 0, 'RssFile': 0, 'VmHWM': 0}
    samples = 0
    while proc.poll() is None:
        fields = _status_bytes(proc.pid)
        if 'RssAnon' in fields:
            samples += 1
            for name in peak:
                peak[name] = max(peak[name], fields.get(name, 0))
        time.sleep(SAMPLE_INTERVAL_S)
    stderr = proc.stderr.read().decode(errors='replace') if proc.stderr else ''
    if proc.returncode:
        msg = f'{" ".join(command)} exited with {proc.returncode}: {stderr.strip()[-500:]}'
        raise RuntimeError(msg)
    return Peak(peak['RssAnon'], peak['RssFile'], peak['VmHWM'], samples)


def _measure(ctx: Context, bag: Bag) -> list[Measurement]:
    """Peak RssAnon, RssFile and RSS (MiB) over the repeats of a run on ``bag``."""
    env = {**os.environ, 'OMP_NUM_THREADS': '1'}
    peaks = []
    for n in range(ctx.settings.memory_repeats):
        out = ctx.tmp / f'memory-{bag.spec.name}-{n}'
        command = [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bag.path),
            '--backend',
            'null',
            '--out',
            str(out),
        ]
        peaks.append(peak_memory(command, env))
        shutil.rmtree(out, ignore_errors=True)
    label = f'{bag.spec.name}, {bag.size_bytes / _MIB:.0f} MiB'
    samples = min(p.samples for p in peaks)
    return [
        Measurement(
            f'peak RssAnon[{label}]',
            'MiB',
            tuple(p.anon / _MIB for p in peaks),
            bag.spec.frames,
            f'max of >= {samples} samples of /proc/<pid>/status',
        ),
        Measurement(
            f'peak RssFile[{label}]',
            'MiB',
            tuple(p.file / _MIB for p in peaks),
            bag.spec.frames,
            'file-backed resident pages (the mapped bag, libraries)',
        ),
        Measurement(
            f'peak RSS[{label}]',
            'MiB',
            tuple(p.rss / _MIB for p in peaks),
            bag.spec.frames,
            'VmHWM: every resident page',
        ),
    ]


def run(ctx: Context) -> ItemResult:
    title = 'Memory: replaybench run --backend null (subprocess)'
    if 'memory_small' not in ctx.bags:
        reason = (
            f'{(ctx.free_bytes or 0) / (1 << 30):.1f} GiB free in {ctx.tmp.parent}; '
            f'the memory item needs {ctx.settings.min_free_bytes / (1 << 30):.1f} GiB'
        )
        return ItemResult(ITEM, title, [], [], [], skipped=reason)
    big = _measure(ctx, ctx.bags['raw'])
    small = _measure(ctx, ctx.bags['memory_small'])
    big_anon, small_anon = big[0], small[0]
    checks = [
        at_most(ITEM, 'peak private memory [raw]', big_anon, LIMIT_MIB),
        ratio(
            ITEM,
            'peak private memory, raw / memory_small',
            big_anon,
            small_anon,
            GROWTH_LIMIT,
            op='<=',
        ),
    ]
    notes = [
        (
            f'Sampling /proc/<pid>/status every {SAMPLE_INTERVAL_S * 1e3:.0f} ms from the parent; '
            "RssAnon = private anonymous memory. The bag is mmap'd: its pages are reclaimable "
            'page cache (RssFile) and not counted. Peak RSS (all resident pages) is listed too.'
        ),
    ]
    return ItemResult(ITEM, title, [*big, *small], checks, notes)
