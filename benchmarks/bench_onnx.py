"""Item f: onnx-cpu through the whole replay against a bare ``InferenceSession.run``.

Model: YOLOX-Nano (416x416) from ``../shared/real/models``; frames: the real astronaut photo
letterboxed into 640x480 (and its mirror image), written as an rgb8 MCAP. Both sides use the
session options of onnx-cpu (two intra-op threads, no spinning). In alternating rounds:

* bare: ``session.run`` on an input tensor prepared beforehand, ms per call (a second bare
  series uses onnxruntime's default spinning threads, for reference);
* replay: ``run_benchmark(backends=['onnx-cpu'], threads=2)`` over the bag (as
  ``replaybench run --threads 2``: OpenCV's letterbox resize gets the same two threads; the
  suite's single cv2 thread is restored afterwards), ms per frame from the
  frames.csv record times (first frame left out): reading, decoding, preprocess, inference and
  postprocess, i.e. everything the replay does between frames (the records themselves are made
  after the pass, see docs/outputs.md).

Run alone: ``python -m benchmarks.bench_onnx [--quick] [--out benchmarks/results/onnx.json]``.
"""

from __future__ import annotations

import csv
import os
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmarks.core import (
    Check,
    Context,
    ItemResult,
    Measurement,
    Sampler,
    interleaved,
    pin_thread_env,
    ratio,
    run_alone,
)

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

    import numpy as np
    import numpy.typing as npt

__all__ = ['DEFAULT_OUT', 'REAL', 'TARGET', 'THREADS', 'main', 'run']

TARGET = 1.10
THREADS = 2
REAL = (Path(__file__).resolve().parents[1] / '..' / 'shared' / 'real').resolve()
MODEL = REAL / 'models' / 'yolox_nano.onnx'
IMAGE = REAL / 'images' / 'astronaut.png'
DEFAULT_OUT = Path(__file__).resolve().parent / 'results' / 'onnx.json'
_SIZE = (640, 480)


def _frames() -> list[npt.NDArray[np.uint8]]:
    """The astronaut letterboxed into 640x480 (BGR), and its mirror image."""
    import cv2
    import numpy as np

    image = cv2.imread(str(IMAGE), cv2.IMREAD_COLOR)
    if image is None:
        msg = f'cannot read {IMAGE}'
        raise RuntimeError(msg)
    side = _SIZE[1]
    canvas = np.full((_SIZE[1], _SIZE[0], 3), 60, np.uint8)
    left = (_SIZE[0] - side) // 2
    canvas[:, left : left + side] = cv2.resize(image, (side, side), interpolation=cv2.INTER_AREA)
    return [canvas, np.ascontiguousarray(canvas[:, ::-1])]


@contextmanager
def _threads_restored() -> Iterator[None]:
    """OpenCV's thread count put back afterwards (a run restores it itself; this guards the
    measurements of this item against any backend that does not)."""
    import cv2

    before = cv2.getNumThreads()
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _session(*, spinning: bool = False) -> Any:
    """A session configured as onnx-cpu configures its own (``spinning``: ORT's default)."""
    import onnxruntime as ort

    from replaybench.backends.onnx_cpu import session_options

    so = session_options(THREADS, spinning=spinning)
    return ort.InferenceSession(str(MODEL), so, providers=['CPUExecutionProvider'])


class _Replays:
    """Repeated ``run_benchmark`` passes; keeps per-pass stage medians and CPU time per frame.

    CPU time per frame = (process CPU time of the pass - that of a one-frame pass of the same
    bag) / (frames - 1): the fixed costs of a run (session, bag hash, output files) cancel.
    """

    def __init__(self, ctx: Context, bag: Path, frames: int) -> None:
        self.ctx = ctx
        self.bag = bag
        self.frames = frames
        self.n = 0
        self.stages: dict[str, list[float]] = {
            'preprocess_ms': [],
            'infer_ms': [],
            'postprocess_ms': [],
            'stages_ms': [],
            'read_decode_ms': [],
            'latency_ms': [],
        }
        self.cpu: list[float] = []

    def _run(self, max_frames: int | None) -> tuple[Path, float]:
        from replaybench.backends.base import BackendOptions
        from replaybench.replay.runner import RunConfig, run_benchmark

        self.n += 1
        out = self.ctx.tmp / f'onnx-run-{self.n}'
        with _threads_restored():
            cpu = time.process_time()
            run_benchmark(
                RunConfig(
                    inputs=[self.bag],
                    backends=['onnx-cpu'],
                    out_dir=out,
                    warmup=0,
                    max_frames=max_frames,
                    report=False,
                    threads=THREADS,
                    options=BackendOptions(model=MODEL, labels='coco', threads=THREADS),
                )
            )
            cpu = time.process_time() - cpu
        return out, cpu

    def sample(self) -> float:
        _, cpu_one = self._run(1)
        out, cpu_all = self._run(None)
        self.cpu.append((cpu_all - cpu_one) / (self.frames - 1) * 1e3)
        with (out / 'frames.csv').open(newline='') as f:
            rows = [r for r in csv.DictReader(f) if r['status'] == 'ok'][1:]
        done = [float(r['done_s']) for r in rows]
        for key in ('preprocess_ms', 'infer_ms', 'postprocess_ms', 'read_decode_ms', 'latency_ms'):
            self.stages[key].append(statistics.median(float(r[key]) for r in rows))
        self.stages['stages_ms'].append(
            statistics.median(
                sum(float(r[k]) for k in ('preprocess_ms', 'infer_ms', 'postprocess_ms'))
                for r in rows
            )
        )
        return (done[-1] - done[0]) / (len(done) - 1) * 1e3


class _Bare:
    """``session.run`` on a ready tensor, ``frames`` calls a sample; keeps CPU time too."""

    def __init__(self, frames: int, *, spinning: bool = False) -> None:
        from replaybench.detector.preprocess import letterbox
        from replaybench.detector.spec import default_preprocess

        self.frames = frames
        self.session = _session(spinning=spinning)
        pre = default_preprocess('yolox', (416, 416))
        tensor = letterbox(_frames()[0], 'bgr8', pre)[0].copy()
        self.feed = {self.session.get_inputs()[0].name: tensor}
        for _ in range(3):
            self.session.run(None, self.feed)
        self.cpu: list[float] = []
        name = 'bare session.run, spinning threads' if spinning else 'bare session.run'
        self.sampler = Sampler(name, 'ms/frame', self.sample, frames)

    def sample(self) -> float:
        cpu = time.process_time()
        start = time.perf_counter()
        for _ in range(self.frames):
            self.session.run(None, self.feed)
        wall = (time.perf_counter() - start) / self.frames * 1e3
        self.cpu.append((time.process_time() - cpu) / self.frames * 1e3)
        return wall


def _write_bag(ctx: Context, frames: int) -> Path:
    from benchmarks.data import BagSpec, warm_page_cache, write_bag

    spec = BagSpec('onnx_astronaut', _SIZE, frames, 'rgb8')
    bag = write_bag(ctx.tmp / 'onnx_astronaut.mcap', spec, _frames())
    warm_page_cache(bag.path)
    return bag.path


def _kept(name: str, unit: str, values: list[float], n: int, frames: int) -> Measurement:
    """The last ``n`` values (the rounds ``interleaved`` kept) as a Measurement."""
    return Measurement(name, unit, tuple(values[len(values) - n :]), frames)


def _load() -> str:
    try:
        one, five, _ = os.getloadavg()
    except OSError:
        return 'load average unknown'
    return f'load average {one:.1f} (1 min), {five:.1f} (5 min) on {os.cpu_count()} CPUs'


def run(ctx: Context) -> ItemResult:
    title = f'onnx-cpu (YOLOX-Nano 416x416, {THREADS} threads) vs bare session.run'
    if not (MODEL.is_file() and IMAGE.is_file()):
        return ItemResult('f', title, [], [], [], skipped=f'{REAL} not present')
    import onnxruntime as ort

    frames = 6 if ctx.settings.quick else 60
    bag = _write_bag(ctx, frames)
    replays = _Replays(ctx, bag, frames)
    bare_runs, spin_runs = _Bare(frames), _Bare(frames, spinning=True)
    load_before = _load()
    bare, replay, spinning = interleaved(
        [
            bare_runs.sampler,
            Sampler('onnx-cpu replay', 'ms/frame', replays.sample, frames),
            spin_runs.sampler,
        ],
        ctx.settings.repeats,
    )
    n = len(replay.values)
    stage_ms = {
        key: _kept(f'onnx-cpu {key} (median per pass)', 'ms', values, n, frames)
        for key, values in replays.stages.items()
    }
    bare_cpu = _kept('bare session.run, CPU time', 'ms/frame', bare_runs.cpu, n, frames)
    replay_cpu = _kept('onnx-cpu replay, CPU time', 'ms/frame', replays.cpu, n, frames)
    checks: list[Check] = [
        ratio('f', 'onnx-cpu replay vs bare session.run', replay, bare, TARGET, op='<='),
        ratio(
            'f',
            'onnx-cpu replay vs bare session.run, CPU time per frame',
            replay_cpu,
            bare_cpu,
            None,
            op='<=',
            note='process CPU time (all threads); insensitive to other processes',
        ),
        ratio(
            'f',
            'onnx-cpu preprocess+infer+postprocess vs bare session.run',
            stage_ms['stages_ms'],
            bare,
            None,
            op='<=',
        ),
        ratio(
            'f',
            'onnx-cpu replay vs bare session.run with spinning threads',
            replay,
            spinning,
            None,
            op='<=',
            note='onnxruntime default session.intra_op.allow_spinning=1',
        ),
    ]
    notes = [
        (
            f'{frames} frames of 640x480 rgb8 per pass; onnxruntime {ort.__version__}, '
            f'intra-op threads {THREADS}, inter-op 1, sequential, graph optimisation all, '
            'no spinning (replaybench.backends.onnx_cpu.session_options) on both sides; '
            f'the replay runs with threads={THREADS} (cv2 too, as --threads {THREADS}); '
            'a third series times a bare session with spinning threads (onnxruntime default).'
        ),
        (
            'replay ms/frame = (done time of the last frame - done time of the first) / '
            '(frames - 1) from frames.csv; the first frame (session warm-up) is left out.'
        ),
        f'{load_before} before, {_load()} after the rounds.',
    ]
    measurements = [bare, replay, spinning, bare_cpu, replay_cpu, *stage_ms.values()]
    return ItemResult('f', title, measurements, checks, notes)


def main(argv: Sequence[str] | None = None) -> int:
    """Run item f alone, print the figures and write them as JSON."""
    pin_thread_env()
    return run_alone(
        run,
        prog='python -m benchmarks.bench_onnx',
        description='onnx-cpu end to end vs a bare session.run (YOLOX-Nano, 2 threads).',
        out=DEFAULT_OUT,
        argv=argv,
        width=55,
    )


if __name__ == '__main__':
    sys.exit(main())
