"""Camera rigs: ``--pipelines shared`` against ``per-topic`` on the real clock, ratios in one run.

    python -m benchmarks.rig [--repeats 3] [--out PATH]

Both on ``rig.mcap`` (``replaybench fixtures --rig 4``: four JPEG cameras at 30 Hz, the last
one 2 frames late), written here into a temporary folder:

* **waiting**: a backend that waits 20 ms per frame without using the CPU (``time.sleep``,
  which releases the GIL), 320x240, 90 frames a camera, ``--rate recorded``. One shared
  instance can serve at most 50 of the 120 frames a second (drops >= 55 %); one instance per
  camera serves them all (drops <= 1 %). The same case runs on a virtual clock in
  ``tests/replay/test_pipelines.py``.
* **hsv at max**: ``hsv`` at 640x480, 150 frames a camera, ``--threads 1`` (each pipeline's
  OpenCV on one thread), ``--rate max``: the aggregate throughput (frames measured over the
  time from the first release to the last detection) of ``per-topic`` over ``shared``; the
  median of ``--repeats`` pairs, each pair run back to back. Beside it its ceiling on this
  machine: cores x serial / shared, where serial is the shared node without its read-ahead
  thread (``prefetch=0``: one thread, one core busy). No frame can cost less CPU time than it
  does there, so C cores serve at most C times its frames a second; a shared run at ``max``
  already decodes ahead in a second thread, which puts the ceiling under 2x on two cores.
* **worker processes**: the hsv case again with ``--workers processes`` (each pipeline's
  ``hsv`` in a worker process, frames handed over in shared memory), and the ``busy`` backend
  spinning 5 ms of CPU time a frame in Python (the GIL held all along) at 320x240, shared against
  per-topic with threads and with processes: where ``detect`` holds the GIL, threads stay near
  1x and processes go to the cores.
* **GIL**: ``HsvBackend.detect`` on decoded frames in one thread and in two at once (no
  replay): two threads' throughput over one thread's, the share of ``detect`` that runs
  outside the GIL.
* **processes**: the same ``detect`` in two worker processes at once, each reading the decoded
  frames from one ``multiprocessing.shared_memory`` block (no copy, no pickling of frames): two
  processes' throughput over one thread's, the other way of giving each camera a core, beside
  the two threads.

Writes benchmarks/results/rig.json and prints the figures. Not part of ``python -m
benchmarks``: it writes its own bag.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.backends.base import Availability, BackendOptions
    from replaybench.types import BackendResult, Frame

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / 'benchmarks' / 'results' / 'rig.json'
WAIT_S = 0.020
#: the busy backend spinning 5 ms of its thread's CPU time per frame, in Python: the GIL held
BUSY = {'busy_ms': '5', 'busy_clock': 'cpu'}


class Waiting:
    """Sleeps ``WAIT_S`` per frame: a device of fixed service time that leaves the CPU idle."""

    name: ClassVar[str] = 'waiting'
    description: ClassVar[str] = 'sleeps 20 ms a frame'

    @classmethod
    def available(cls) -> Availability:
        from replaybench.backends.base import Availability

        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:  # noqa: ARG002 - the protocol's signature
        from replaybench.types import BackendResult, StageTimes

        time.sleep(WAIT_S)
        return BackendResult((), StageTimes(infer_ns=int(WAIT_S * 1e9)))

    def info(self) -> dict[str, Any]:
        return {'wait_ms': WAIT_S * 1e3}

    def close(self) -> None:
        pass


def _run(
    bag: Path,
    backend: str,
    pipelines: str,
    rate: str,
    threads: int | None,
    prefetch: int = 4,
    workers: str = 'threads',
) -> Any:
    from replaybench.backends.base import BackendOptions
    from replaybench.replay.rate import parse_rate
    from replaybench.replay.runner import RunConfig, run_benchmark
    from replaybench.replay.sessions import make_backend

    def factory(name: str, options: BackendOptions) -> Any:
        return Waiting() if name == 'waiting' else make_backend(name, options)

    config = RunConfig(
        inputs=[bag],
        backends=[backend],
        out_dir=None,
        rate=parse_rate(rate),
        pipelines=pipelines,
        threads=threads,
        report=False,
        hash_inputs=False,
        prefetch=prefetch,
        workers=workers,
        options=BackendOptions(extra=BUSY if backend == 'busy' else {}),
    )
    return run_benchmark(config, backend_factory=factory if backend == 'waiting' else None)


def _drop_rate(outcome: Any) -> float:
    records = outcome.records
    return float(sum(r.dropped for r in records) / len(records))


def _throughput(outcome: Any) -> float:
    """Frames detected per second, from the first release to the last detection."""
    ok = [r for r in outcome.records if r.status == 'ok']
    span = max(r.done_s for r in ok) - min(r.release_s for r in ok)
    return float(len(ok) / span)


def _gil_share(bag: Path, seconds: float = 2.0) -> dict[str, float]:
    """hsv's ``detect`` in one thread, then in two at once: frames a second of each."""
    import cv2

    from replaybench.backends.hsv import HsvBackend
    from replaybench.decode import decode_image
    from replaybench.sources import open_source
    from replaybench.types import Frame

    frames = []
    with open_source(bag) as source:
        topic = '/rig/cam0/image_raw/compressed'
        for _, raw in zip(range(8), source.messages(topics=[topic]), strict=False):
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
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        backend = HsvBackend()
        backend.open()

        def spin(counts: list[int], until: float) -> None:
            n = 0
            while time.perf_counter() < until:
                backend.detect(frames[n % len(frames)])
                n += 1
            counts.append(n)

        one: list[int] = []
        spin(one, time.perf_counter() + seconds)
        two: list[int] = []
        until = time.perf_counter() + seconds
        workers = [threading.Thread(target=spin, args=(two, until)) for _ in range(2)]
        for w in workers:
            w.start()
        for w in workers:
            w.join()
    finally:
        cv2.setNumThreads(before)
    return {
        'one_thread_fps': one[0] / seconds,
        'two_threads_fps': sum(two) / seconds,
        'ratio': sum(two) / one[0],
    }


def _process_share(bag: Path, seconds: float = 2.0) -> dict[str, float]:
    """hsv's ``detect`` in two worker processes at once, the decoded frames in one shared
    memory block: frames a second over a window both start together."""
    import numpy as np

    from replaybench.decode import decode_image
    from replaybench.sources import open_source

    with open_source(bag) as source:
        topic = '/rig/cam0/image_raw/compressed'
        images = [
            np.ascontiguousarray(decode_image(raw).image)
            for _, raw in zip(range(8), source.messages(topics=[topic]), strict=False)
        ]
    return _aligned_processes(np.stack(images), seconds)


def _aligned_processes(block_frames: Any, seconds: float) -> dict[str, float]:
    """Two worker processes (spawned: nothing of this process inherited) that wait for one
    common start, then spin ``seconds`` each."""
    import multiprocessing as mp
    from multiprocessing import shared_memory

    import numpy as np

    block = shared_memory.SharedMemory(create=True, size=block_frames.nbytes)
    try:
        np.ndarray(block_frames.shape, dtype=np.uint8, buffer=block.buf)[:] = block_frames
        context = mp.get_context('spawn')
        results = context.Queue()
        ready = context.Barrier(3)
        workers = [
            context.Process(
                target=_aligned_worker,
                args=(block.name, block_frames.shape, seconds, ready, results),
            )
            for _ in range(2)
        ]
        for w in workers:
            w.start()
        ready.wait(timeout=120)  # both imported and opened: the window starts now
        counts = [results.get(timeout=120) for _ in workers]
        for w in workers:
            w.join()
    finally:
        block.close()
        block.unlink()
    return {'two_processes_fps': sum(counts) / seconds}


def _aligned_worker(
    name: str, shape: tuple[int, ...], seconds: float, ready: Any, out: Any
) -> None:
    """One worker: ``HsvBackend.detect`` (OpenCV on one thread) on views of the shared block,
    counted from the common start."""
    from multiprocessing import shared_memory

    import cv2
    import numpy as np

    from replaybench.backends.hsv import HsvBackend
    from replaybench.types import Frame

    cv2.setNumThreads(1)
    block = shared_memory.SharedMemory(name=name)
    try:
        images = np.ndarray(shape, dtype=np.uint8, buffer=block.buf)
        frames = [Frame('/cam', i, i, i, 'cam', images[i], 'bgr8', 'bgr8') for i in range(shape[0])]
        backend = HsvBackend()
        backend.open()
        backend.detect(frames[0])
        ready.wait(timeout=120)
        until = time.perf_counter() + seconds
        n = 0
        while time.perf_counter() < until:
            backend.detect(frames[n % len(frames)])
            n += 1
        out.put(n)
        del frames, images
    finally:
        block.close()


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog='python -m benchmarks.rig', description=__doc__)
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--out', type=Path, default=OUT)
    return parser.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse(argv)
    from replaybench.fixtures.rig import write_rig_mcap

    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        small = write_rig_mcap(Path(tmp) / 'rig_320.mcap', 90, (320, 240), 4)
        large = write_rig_mcap(Path(tmp) / 'rig_640.mcap', 150, (640, 480), 4)
        waiting = {
            mode: _drop_rate(_run(small, 'waiting', mode, 'recorded', None))
            for mode in ('shared', 'per-topic')
        }
        pairs: list[dict[str, float]] = []
        busy: list[dict[str, float]] = []
        for _ in range(args.repeats):
            shared = _throughput(_run(large, 'hsv', 'shared', 'max', 1))
            serial = _throughput(_run(large, 'hsv', 'shared', 'max', 1, prefetch=0))
            per_topic = _throughput(_run(large, 'hsv', 'per-topic', 'max', 1))
            in_processes = _throughput(
                _run(large, 'hsv', 'per-topic', 'max', 1, workers='processes')
            )
            pairs.append(
                {
                    'shared_fps': shared,
                    'shared_serial_fps': serial,
                    'per_topic_fps': per_topic,
                    'per_topic_processes_fps': in_processes,
                }
            )
            busy.append(
                {
                    'shared_fps': _throughput(_run(small, 'busy', 'shared', 'max', 1)),
                    'per_topic_fps': _throughput(_run(small, 'busy', 'per-topic', 'max', 1)),
                    'per_topic_processes_fps': _throughput(
                        _run(small, 'busy', 'per-topic', 'max', 1, workers='processes')
                    ),
                }
            )
        gil = _gil_share(large)
        processes = _process_share(large)
    ratios = [p['per_topic_fps'] / p['shared_fps'] for p in pairs]
    serial_ratios = [p['per_topic_fps'] / p['shared_serial_fps'] for p in pairs]
    process_ratios = [p['per_topic_processes_fps'] / p['shared_fps'] for p in pairs]
    cores = len(os.sched_getaffinity(0))
    # the most any pipelines can reach over shared here: each frame costs at least the CPU
    # time it takes the serial run (one thread, one core busy), so C cores serve at most C
    # times the serial run's frames a second
    ceilings = [cores * p['shared_serial_fps'] / p['shared_fps'] for p in pairs]
    process_over_threads = [p['per_topic_processes_fps'] / p['per_topic_fps'] for p in pairs]
    busy_threads = [b['per_topic_fps'] / b['shared_fps'] for b in busy]
    busy_processes = [b['per_topic_processes_fps'] / b['shared_fps'] for b in busy]
    document = {
        'measured_at': dt.datetime.now(dt.UTC).isoformat(timespec='seconds'),
        'cores': cores,
        'load_average_before': [round(v, 2) for v in load_before],
        'load_average_after': [round(v, 2) for v in os.getloadavg()],
        'waiting_20ms_4x30hz_recorded': {
            'shared_drop_rate': waiting['shared'],
            'per_topic_drop_rate': waiting['per-topic'],
            'targets': {'shared_drop_rate_min': 0.55, 'per_topic_drop_rate_max': 0.01},
        },
        'hsv_640x480_4_cameras_max_threads_1': {
            'pairs': pairs,
            'ratio_median': statistics.median(ratios),
            'ratios': ratios,
            'target': 1.7,
            # the shared node without its read-ahead thread: one core, the model the 2x limit
            # of the target assumes
            'over_serial_shared_median': statistics.median(serial_ratios),
            'over_serial_shared': serial_ratios,
            # cores x serial / shared: the ceiling of ratio_median on this machine
            'ceiling_over_shared_median': statistics.median(ceilings),
            'ceiling_over_shared': ceilings,
            # --workers processes: each pipeline's hsv in a worker process
            'processes_over_shared_median': statistics.median(process_ratios),
            'processes_over_shared': process_ratios,
            'processes_over_threads_median': statistics.median(process_over_threads),
            'processes_over_threads': process_over_threads,
        },
        'busy_5ms_cpu_320x240_4_cameras_max_threads_1': {
            'runs': busy,
            'per_topic_threads_over_shared_median': statistics.median(busy_threads),
            'per_topic_threads_over_shared': busy_threads,
            'per_topic_processes_over_shared_median': statistics.median(busy_processes),
            'per_topic_processes_over_shared': busy_processes,
        },
        'hsv_detect_two_threads_over_one': gil,
        'hsv_detect_two_processes_shared_memory': {
            **processes,
            'ratio_over_one_thread': processes['two_processes_fps'] / gil['one_thread_fps'],
        },
    }
    args.out.write_text(json.dumps(document, indent=1) + '\n', encoding='utf-8')
    print(
        f'waiting 20 ms, 4 cameras at 30 Hz: drops shared {waiting["shared"]:.1%}, '
        f'per-topic {waiting["per-topic"]:.1%}'
    )
    print(
        f'hsv 640x480 at max, 4 cameras, --threads 1: per-topic / shared '
        f'{statistics.median(ratios):.2f}x (pairs: {", ".join(f"{r:.2f}" for r in ratios)}); '
        f'over shared without read-ahead (prefetch=0) {statistics.median(serial_ratios):.2f}x'
    )
    print(
        f'  the most per-topic can reach over shared on {cores} cores: cores x serial / shared '
        f'= {statistics.median(ceilings):.2f}x (target 1.7x)'
    )
    print(
        f'hsv, --workers processes: over shared {statistics.median(process_ratios):.2f}x, over '
        f'threads {statistics.median(process_over_threads):.2f}x'
    )
    print(
        'busy 5 ms of CPU in Python (the GIL held), 4 cameras at max: per-topic over shared, '
        f'threads {statistics.median(busy_threads):.2f}x, processes '
        f'{statistics.median(busy_processes):.2f}x'
    )
    print(f'hsv detect, two threads over one: {gil["ratio"]:.2f}x')
    print(
        'hsv detect, two processes (frames in shared memory) over one thread: '
        f'{processes["two_processes_fps"] / gil["one_thread_fps"]:.2f}x'
    )
    print(f'load average before {load_before[0]:.2f}, after {os.getloadavg()[0]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
