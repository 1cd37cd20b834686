"""Run every item, write the results as JSON and print the figures next to their targets."""

from __future__ import annotations

import argparse
import datetime as dt
import importlib
import importlib.util
import os
import shutil
import sys
import tempfile
import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmarks.core import Context, ItemResult, Settings, fix_threads
from benchmarks.data import BagSpec, warm_page_cache, write_bag

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Sequence
    from types import ModuleType

    from benchmarks.core import Check
    from benchmarks.data import Bag

__all__ = [
    'DEFAULT_OUT',
    'ITEMS',
    'ON_REQUEST_ITEMS',
    'OPTIONAL_ITEMS',
    'SCHEMA_VERSION',
    'item_modules',
    'main',
    'render_table',
    'run_suite',
]

#: Version of the bench.json layout.
SCHEMA_VERSION = 1
DEFAULT_OUT = Path(__file__).resolve().parent / 'results' / 'bench.json'
#: Modules with a ``run(ctx: Context) -> ItemResult``, in order.
ITEMS = (
    'benchmarks.bench_reading',
    'benchmarks.bench_harness',
    'benchmarks.bench_hsv',
    'benchmarks.bench_segmentation',
    'benchmarks.bench_pipeline',
    'benchmarks.bench_memory',
)
#: Optional items, run when the module exists.
OPTIONAL_ITEMS = ('benchmarks.bench_onnx', 'benchmarks.bench_tags')
#: Items run only when --items names them (item g starts Ray clusters: docs/sweep.md).
ON_REQUEST_ITEMS = ('benchmarks.bench_sweep',)


def _specs(settings: Settings, names: Collection[str], memory: bool) -> list[BagSpec]:
    """The bags named in ``names``; the small memory bag only when ``memory``."""
    big, n = settings.big, settings.raw_frames
    specs = [
        BagSpec('raw', big, n, 'rgb8'),
        BagSpec('zstd', big, n, 'rgb8', 'zstd'),
        BagSpec('jpeg', big, settings.jpeg_frames, 'jpeg'),
        BagSpec('jpeg_small', settings.small, settings.jpeg_frames, 'jpeg'),
        BagSpec('memory_small', big, settings.memory_small_frames, 'rgb8'),
    ]
    return [s for s in specs if s.name in names and (memory or s.name != 'memory_small')]


def _write_bags(ctx: Context, names: Collection[str], log: Callable[[str], None]) -> None:
    memory = (ctx.free_bytes or 0) >= ctx.settings.min_free_bytes
    for spec in _specs(ctx.settings, names, memory):
        start = time.perf_counter()
        bag = write_bag(ctx.tmp / f'{spec.name}.mcap', spec, ctx.scene_frames(spec.size))
        warm_page_cache(bag.path)
        ctx.bags[spec.name] = bag
        log(
            f'wrote {spec.name}: {spec.describe()}, {bag.size_bytes / (1 << 20):.0f} MiB '
            f'({time.perf_counter() - start:.1f} s)'
        )


def _keys(module: ModuleType) -> set[str]:
    """What ``--items`` may call a module: its ITEM letter and its name without ``bench_``."""
    short = module.__name__.rsplit('.', 1)[-1].removeprefix('bench_')
    item = getattr(module, 'ITEM', None)
    return {short, item} if isinstance(item, str) else {short}


def item_modules(selected: Collection[str] | None, log: Callable[[str], None]) -> list[ModuleType]:
    """The item modules in order (optional ones when present), filtered by ``selected``."""
    modules = [importlib.import_module(name) for name in ITEMS]
    for name in OPTIONAL_ITEMS:
        if importlib.util.find_spec(name) is None:
            continue
        module = importlib.import_module(name)
        if callable(getattr(module, 'run', None)):
            modules.append(module)
        else:
            log(f'{name} has no run(ctx) -> ItemResult; not included')
    if not selected:
        return modules
    modules += [importlib.import_module(name) for name in ON_REQUEST_ITEMS]
    known = set().union(*(_keys(m) for m in modules))
    unknown = sorted(set(selected) - known)
    if unknown:
        msg = f'unknown item(s) {", ".join(unknown)}; known: {", ".join(sorted(known))}'
        raise SystemExit(msg)
    return [m for m in modules if _keys(m) & set(selected)]


def run_suite(
    settings: Settings, log: Callable[[str], None], items: Collection[str] | None = None
) -> dict[str, Any]:
    """Generate the data into a temp folder, run the items, return the bench.json document.

    ``items`` selects items by letter or short name (``a``, ``pipeline``); None runs all.
    """
    modules = item_modules(items, log)
    threads = fix_threads()
    started = dt.datetime.now(dt.UTC)
    t0 = time.perf_counter()
    results: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix='replaybench-bench-') as tmp:
        ctx = Context(settings, Path(tmp), free_bytes=shutil.disk_usage(tmp).free)
        _write_bags(ctx, {b for m in modules for b in getattr(m, 'BAGS', ())}, log)
        results.extend(_run_item(module.run, ctx, log) for module in modules)
        bags: list[Bag] = list(ctx.bags.values())
    return _document(settings, threads, bags, results, started, time.perf_counter() - t0)


def _run_item(
    runner: Callable[[Context], ItemResult], ctx: Context, log: Callable[[str], None]
) -> dict[str, Any]:
    """Run one item; its JSON with the wall time and the load average before and after."""
    load_before = os.getloadavg()
    start = time.perf_counter()
    result = runner(ctx)
    wall = time.perf_counter() - start
    log(f'item {result.item} done ({wall:.1f} s)')
    return {**result.as_dict(), 'wall_s': wall, 'load_average': [load_before, os.getloadavg()]}


def _runner_settings() -> dict[str, Any]:
    from dataclasses import fields

    from replaybench.replay.runner import RunConfig

    defaults = {f.name: f.default for f in fields(RunConfig) if f.name in ('prefetch', 'rate')}
    return {
        'threads': 1,
        'report': False,
        'prefetch': defaults.get('prefetch'),
        'note': 'run_benchmark at max rate with its own defaults otherwise',
    }


def _document(
    settings: Settings,
    threads: dict[str, Any],
    bags: Sequence[Bag],
    results: Sequence[dict[str, Any]],
    started: dt.datetime,
    wall_s: float,
) -> dict[str, Any]:
    from replaybench.results.machine import environment

    checks = [c for r in results for c in r['checks']]
    return {
        'schema_version': SCHEMA_VERSION,
        'suite': 'replaybench benchmarks',
        'mode': 'quick' if settings.quick else 'full',
        'started_at': started.isoformat(),
        'wall_s': wall_s,
        'command': [sys.executable, *sys.argv],
        'environment': environment(),
        'niceness': os.getpriority(os.PRIO_PROCESS, 0),
        'threads': threads,
        'settings': asdict(settings),
        'runner': _runner_settings(),
        'data': [bag.as_dict() for bag in bags],
        'items': list(results),
        'totals': {
            'checks': sum(c['passed'] is not None for c in checks),
            'passed': sum(c['passed'] is True for c in checks),
            'failed': sum(c['passed'] is False for c in checks),
        },
    }


def _number(value: float, unit: str) -> str:
    if unit == 'x':
        return f'{value:.2f}x'
    if unit == 'of frames':
        return f'{value:.0%}'
    if unit == 'ms':
        return f'{value:.3f} ms'
    return f'{value:.1f} {unit}'


def _check_row(check: Check) -> list[str]:
    spread = f'{_number(check.low, check.unit)} .. {_number(check.high, check.unit)}'
    target = '-' if check.target is None else f'{check.op} {_number(check.target, check.unit)}'
    verdict = {True: 'PASS', False: 'FAIL', None: 'info'}[check.passed]
    return [check.item, check.name, _number(check.value, check.unit), spread, target, verdict]


def _table(header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = [
        '  '.join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
        for row in [header, ['-' * w for w in widths], *rows]
    ]
    return '\n'.join(lines)


def render_table(document: dict[str, Any]) -> str:
    """The measurements and the checks of a bench.json document as text tables."""
    measured = [
        [
            item['item'],
            m['name'],
            f'{m["median"]:.4g}',
            f'{m["min"]:.4g} .. {m["max"]:.4g}',
            m['unit'],
            str(len(m['repeats'])),
        ]
        for item in document['items']
        for m in item['measurements']
    ]
    checks = [_check_row(_check_from_dict(c)) for item in document['items'] for c in item['checks']]
    skipped = [
        f'item {i["item"]} skipped: {i["skipped"]}' for i in document['items'] if i['skipped']
    ]
    data = [
        [bag['name'], bag['description'], f'{bag["size_bytes"] / (1 << 20):.0f} MiB']
        for bag in document['data']
    ]
    totals = document['totals']
    quick = (
        ['quick run: tiny data, the figures say nothing about performance']
        if document['mode'] == 'quick'
        else []
    )
    return '\n\n'.join(
        [
            _table(['bag', 'contents', 'size'], data),
            _table(['item', 'measurement', 'median', 'min .. max', 'unit', 'n'], measured),
            _table(['item', 'figure', 'measured', 'spread', 'target', 'result'], checks),
            *skipped,
            (
                f'{totals["passed"]} of {totals["checks"]} targets met, {totals["failed"]} missed '
                f'({document["mode"]} run, {document["wall_s"]:.0f} s, '
                f'cv2 threads {document["threads"]["cv2.getNumThreads"]}, '
                f'nice {document.get("niceness", 0)}).'
            ),
            *quick,
        ]
    )


def _check_from_dict(data: dict[str, Any]) -> Check:
    from benchmarks.core import Check

    return Check(**{k: v for k, v in data.items() if k != 'passed'})


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog='python -m benchmarks', description='Run the replaybench benchmark suite.'
    )
    parser.add_argument('--quick', action='store_true', help='tiny data, one repeat (smoke test)')
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT, help='where bench.json goes')
    parser.add_argument('--strict', action='store_true', help='exit 1 when a target is missed')
    parser.add_argument(
        '--items',
        type=lambda text: [part.strip() for part in text.split(',') if part.strip()],
        default=None,
        help='comma-separated items to run, by letter or name (a,b or reading,pipeline); '
        'default: all',
    )
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line entry point; returns the exit status."""
    from replaybench.results.atomic import write_json_atomic

    args = _parse(argv)
    settings = Settings.tiny() if args.quick else Settings.full()

    def log(line: str) -> None:
        print(f'[bench] {line}', file=sys.stderr, flush=True)

    document = run_suite(settings, log, args.items)
    write_json_atomic(args.out, document)
    print(render_table(document))
    print(f'\nwrote {args.out}')
    return 1 if args.strict and document['totals']['failed'] else 0
