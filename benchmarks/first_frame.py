"""How long from process start to the first frame entering the ``null`` backend, by bag size?

    python -m benchmarks.first_frame [--sizes-mb 200 4000] [--chunks 20000] [--dir /tmp]
                                     [--repeats 3]

Targets: a first frame in at most 0.40 s (``TARGET_S``), and each larger bag within 10 %
(``RATIO_MAX``) of the first (200 MB) one: nothing the run does before its first frame may
grow with the bag. The reader opens an MCAP by its summary alone, whose chunk indexes are read
with array operations, and reads a chunk's MessageIndex records when it reaches the chunk; the
bag's CameraInfo messages are read only by a backend that reads a
frame's camera info (the null backend does not), else after the passes; every input's sha256
is taken after the passes.

The size bags are ROS 2 MCAPs of 1920x1080 ``rgb8`` frames (6.2 MB each), each with its
``CameraInfo`` as a camera driver publishes it, in uncompressed chunks,
written **sparse**: the frames are black, and the runs of zero bytes are left as holes in the
file, so a 4 GB bag costs a few seconds and little disk. The chunk bags (``--chunks N``) hold
N chunks of one small 32x24 ``rgb8`` frame and its ``CameraInfo`` each (about 3 kB a chunk):
the index of a 20 GB recording at 1 MiB chunks, in 60 MB. Bags are written to ``--dir`` (not
the repository) and removed afterwards. Per bag, ``replaybench run BAG --backend null
--max-frames 20 --no-report`` is started ``--repeats`` times as a fresh process (``python -m
replaybench``, with the null backend's ``detect`` wrapped to print the system-wide monotonic
clock at its first frame); the parent reads the same clock just before starting the process.
The same runs with ``--no-hash`` are the baseline of the same session: if hashing (or anything
else) came before the first frame, the two would part as the bag grows. The figures printed
are medians, with the best beside them, and the load average before each bag's runs; they
include the interpreter's start and replaybench's imports. On a busy machine the figures
carry its load: the targets are for an idle one.

The imports are timed as an installed package runs them, from cached bytecode (``pip install``
compiles it; an editable install writes it on first use): the child processes run with the
bytecode cache on (``PYTHONDONTWRITEBYTECODE`` removed) and kept in a folder of their own
(``PYTHONPYCACHEPREFIX``), and one untimed run before the timed ones fills it. That first run,
which compiles every module, is reported too (``first_run_s``). Writes
benchmarks/results/first_frame.json; the last line printed says whether the targets are met
(exit status 0) or which are missed (1). Not part of ``python -m benchmarks``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import IO, Any, cast

__all__ = [
    'RATIO_MAX',
    'TARGET_S',
    'main',
    'time_to_first_frame',
    'verdict',
    'write_chunk_bag',
    'write_sparse_bag',
]

TARGET_S = 0.40
#: a larger bag's first frame at most this many times the first bag's
RATIO_MAX = 1.10
WIDTH, HEIGHT = 1920, 1080
SMALL_WIDTH, SMALL_HEIGHT = 32, 24
_BLOCK = 1 << 20
_RESULTS = Path(__file__).resolve().parent / 'results' / 'first_frame.json'

_CHILD = """
import sys, time
from replaybench.backends.null import NullBackend
_detect = NullBackend.detect
_seen = []
def detect(self, frame):
    if not _seen:
        _seen.append(1)
        print(f'FIRST_FRAME {time.monotonic():.6f}', file=sys.stderr, flush=True)
    return _detect(self, frame)
NullBackend.detect = detect
sys.argv = ['replaybench', *sys.argv[1:]]
from replaybench.cli import main
main()
"""


class _SparseStream:
    """A binary file that leaves 1 MiB-aligned blocks of zeros as holes (seeks past them)."""

    def __init__(self, file: IO[bytes]) -> None:
        self.file = file
        self.pos = 0
        self.zeros = bytes(_BLOCK)

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data).cast('B')
        done = 0
        while done < len(view):
            room = _BLOCK - self.pos % _BLOCK
            part = view[done : done + room]
            if len(part) == room and part == self.zeros[: len(part)]:
                self.file.seek(len(part), os.SEEK_CUR)
            else:
                self.file.write(part)
            done += len(part)
            self.pos += len(part)
        return len(view)

    def tell(self) -> int:
        return self.pos

    def flush(self) -> None:
        self.file.flush()

    def close(self) -> None:
        self.file.truncate(self.pos)  # a hole at the end still counts in the file's size
        self.file.close()


def write_sparse_bag(path: Path, size_bytes: int) -> int:
    """A ROS 2 MCAP of black 1920x1080 rgb8 frames, about ``size_bytes`` long, written sparse;
    returns the frames written."""
    import numpy as np
    from mcap.writer import CompressionType, Writer

    frame = np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)
    frames = max(1, size_bytes // frame.nbytes)
    stream = _SparseStream(path.open('wb'))
    writer: Any = Writer(cast('Any', stream), chunk_size=8 << 20, compression=CompressionType.NONE)
    _write_frames(writer, frame, frames)
    writer.finish()
    stream.close()
    return frames


def _write_frames(writer: Any, frame: Any, frames: int) -> None:
    """Start ``writer`` (an MCAP writer) and write ``frames`` copies of ``frame`` (rgb8) on
    ``/camera/image_raw``, each after its CameraInfo on ``/camera/camera_info``."""
    from replaybench.fixtures.writer import camera_info, stamp_ns
    from replaybench.msgs import (
        CAMERA_INFO,
        IMAGE,
        ros2msg_schema,
        serialize_camera_info,
        serialize_image,
    )

    writer.start(profile='ros2', library='replaybench benchmarks')
    schema = writer.register_schema(
        name=IMAGE, encoding='ros2msg', data=ros2msg_schema(IMAGE).encode()
    )
    channel = writer.register_channel(
        topic='/camera/image_raw', message_encoding='cdr', schema_id=schema
    )
    info_schema = writer.register_schema(
        name=CAMERA_INFO, encoding='ros2msg', data=ros2msg_schema(CAMERA_INFO).encode()
    )
    info_channel = writer.register_channel(
        topic='/camera/camera_info', message_encoding='cdr', schema_id=info_schema
    )
    size = (frame.shape[1], frame.shape[0])
    for i in range(frames):
        t = stamp_ns(i)
        info = serialize_camera_info(camera_info(size, t, 'camera_optical_frame'))
        writer.add_message(
            channel_id=info_channel, log_time=t, data=info, publish_time=t, sequence=i
        )
        data = serialize_image(t, 'camera_optical_frame', frame, 'rgb8')
        writer.add_message(channel_id=channel, log_time=t, data=data, publish_time=t, sequence=i)


def write_chunk_bag(path: Path, chunks: int) -> int:
    """A ROS 2 MCAP of ``chunks`` uncompressed chunks, each one 32x24 rgb8 frame with its
    CameraInfo (the first chunk also holds the schemas and channels and the first
    CameraInfo); returns the frames written."""
    import numpy as np
    from mcap.writer import CompressionType, Writer

    frame = np.zeros((SMALL_HEIGHT, SMALL_WIDTH, 3), dtype=np.uint8)
    frames = max(1, chunks - 1)
    with path.open('wb') as f:
        # a chunk is closed once it holds more than 1 kB: after each frame
        writer: Any = Writer(f, chunk_size=1024, compression=CompressionType.NONE)
        _write_frames(writer, frame, frames)
        writer.finish()
    return frames


def chunk_count(path: Path) -> int:
    """The chunks an MCAP's summary lists."""
    from mcap.reader import make_reader

    with path.open('rb') as f:
        summary = make_reader(f).get_summary()
    return len(summary.chunk_indexes) if summary is not None else 0


def child_environment(pycache: Path) -> dict[str, str]:
    """The environment of the timed processes: bytecode cached in ``pycache``."""
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONDONTWRITEBYTECODE'}
    env['PYTHONPYCACHEPREFIX'] = str(pycache)
    return env


def time_to_first_frame(
    bag: Path, out: Path, *, hash_inputs: bool, env: dict[str, str] | None = None
) -> tuple[float, float]:
    """(process start to first frame, process start to exit), seconds, for one fresh run."""
    command = [
        sys.executable, '-c', _CHILD, 'run', str(bag), '--backend', 'null',
        '--max-frames', '20', '--no-report', '--force', '--out', str(out),
    ]  # fmt: skip
    if not hash_inputs:
        command.append('--no-hash')
    began = time.monotonic()
    done = subprocess.run(command, capture_output=True, text=True, check=False, env=env)
    ended = time.monotonic()
    if done.returncode != 0:
        msg = f'replaybench run failed ({done.returncode}): {done.stderr.strip()[-500:]}'
        raise RuntimeError(msg)
    for line in done.stderr.splitlines():
        if line.startswith('FIRST_FRAME '):
            return float(line.split()[1]) - began, ended - began
    msg = 'the null backend saw no frame'
    raise RuntimeError(msg)


def verdict(rows: list[dict[str, Any]]) -> tuple[bool, list[str]]:
    """Whether every row meets the targets (its median first frame at most ``TARGET_S``, and
    at most ``RATIO_MAX`` times the first row's), and a line per target missed."""
    missed = []
    base = rows[0]['first_frame_s'] if rows else 0.0
    for row in rows:
        if row['first_frame_s'] > TARGET_S:
            missed.append(f'{row["bag"]}: {row["first_frame_s"]:.3f} s > {TARGET_S} s')
        if base and row['first_frame_s'] > RATIO_MAX * base:
            missed.append(
                f"{row['bag']}: {row['first_frame_s'] / base:.2f}x the {rows[0]['bag']} bag's "
                f'(> {RATIO_MAX:.2f}x)'
            )
    return not missed, missed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m benchmarks.first_frame')
    parser.add_argument('--sizes-mb', type=float, nargs='*', default=[200.0, 4000.0])
    parser.add_argument('--chunks', type=int, nargs='*', default=[20_000])
    parser.add_argument('--dir', type=Path, default=Path(tempfile.gettempdir()))
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--out', type=Path, default=_RESULTS)
    args = parser.parse_args(argv)
    bags: list[tuple[str, float | int]] = [(f'{mb:g} MB', mb) for mb in args.sizes_mb]
    bags += [(f'{n} chunks', n) for n in args.chunks]
    rows = []
    with tempfile.TemporaryDirectory(dir=args.dir, prefix='replaybench-first-frame-') as tmp:
        work = Path(tmp)
        for i, (name, amount) in enumerate(bags):
            bag = work / f'bag-{i}.mcap'
            if i < len(args.sizes_mb):
                frames = write_sparse_bag(bag, int(amount * 1e6))
            else:
                frames = write_chunk_bag(bag, int(amount))
            env = child_environment(work / f'pycache-{i}')
            # untimed: fills the bytecode cache (compiling it is the first run's alone)
            first_run = time_to_first_frame(bag, work / 'run', hash_inputs=True, env=env)[0]
            load = os.getloadavg()
            hashed, plain, totals = [], [], []
            for _ in range(args.repeats):
                first, total = time_to_first_frame(bag, work / 'run', hash_inputs=True, env=env)
                hashed.append(first)
                totals.append(total)
                plain.append(time_to_first_frame(bag, work / 'run', hash_inputs=False, env=env)[0])
            row: dict[str, Any] = {
                'bag': name,
                'size_bytes': bag.stat().st_size,
                'chunks': chunk_count(bag),
                'frames': frames,
                'first_frame_s': statistics.median(hashed),
                'first_frame_best_s': min(hashed),
                'first_frame_no_hash_s': statistics.median(plain),
                'run_s': statistics.median(totals),
                'first_run_s': first_run,
                'load_average': list(load),
            }
            rows.append(row)
            print(
                f'{name:>14} ({row["size_bytes"] / 1e6:.0f} MB, {row["chunks"]} chunks)  '
                f'first frame {row["first_frame_s"]:.3f} s, best {row["first_frame_best_s"]:.3f}'
                f' s (--no-hash {row["first_frame_no_hash_s"]:.3f} s), whole run with its '
                f'sha256 {row["run_s"]:.2f} s (the untimed first run, compiling: '
                f'{first_run:.3f} s); load average {load[0]:.2f}'
            )
            bag.unlink()
    met, missed = verdict(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                'date': dt.datetime.now(dt.UTC).isoformat(timespec='seconds'),
                'load_average': list(os.getloadavg()),
                'repeats': args.repeats,
                'bytecode': 'cached (one untimed run first)',
                'target_s': TARGET_S,
                'ratio_max': RATIO_MAX,
                'met': met,
                'missed': missed,
                'rows': rows,
            },
            indent=2,
        )
        + '\n',
        encoding='utf-8',
    )
    base = rows[0]['bag'] if rows else ''
    if met:
        print(
            f'targets met: every first frame <= {TARGET_S} s and <= {RATIO_MAX:.2f}x '
            f"the {base} bag's"
        )
    else:
        print('targets MISSED: ' + '; '.join(missed))
    return 0 if met else 1


if __name__ == '__main__':
    raise SystemExit(main())
