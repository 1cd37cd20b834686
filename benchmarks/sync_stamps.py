"""What ``--sync`` costs before the first frame: reading the header stamps and pairing them.

    python -m benchmarks.sync_stamps [--frames 300] [--dir /tmp] [--repeats 5]

``--sync`` reads every replayed frame's header stamp before the first frame (8 bytes of a ROS
message; ``replaybench.replay.pairing``) and groups them (``replaybench.replay.sync``). Two
four-camera bags at 30 Hz are written to ``--dir`` and removed afterwards: 640x480 ``rgb8``
frames in uncompressed chunks (``raw``), and 640x480 JPEG frames in zstd chunks (``jpeg``),
whose chunks must be decompressed to reach a header. Per bag, in one process and session,
``--repeats`` times each: the pairing (``pair_inputs`` over the opened input, exact and
``approx:5``), and, as the baseline, one pass that reads and decodes every frame as a replay
does (``replayed`` + ``decode_image``, no backend). Printed and written to
benchmarks/results/sync_stamps.json: medians, the pairing's share of a decode pass, and its
cost per frame. Not part of ``python -m benchmarks``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

__all__ = ['main', 'write_rig_bag']

CAMERAS = 4
WIDTH, HEIGHT = 640, 480
PERIOD_NS = 1_000_000_000 // 30
EPOCH_NS = 1_700_000_000 * 1_000_000_000
RESULTS = Path(__file__).resolve().parent / 'results' / 'sync_stamps.json'


def write_rig_bag(path: Path, frames: int, *, jpeg: bool) -> int:
    """A bag of ``CAMERAS`` cameras, ``frames`` each at 30 Hz with equal stamps; its size."""
    import cv2
    import numpy as np
    from rosbags.typesys import Stores, get_typestore

    from replaybench.fixtures.writer import FixtureMessage, write_ros2_mcap

    store = get_typestore(Stores.ROS2_HUMBLE)
    header, time_t = store.types['std_msgs/msg/Header'], store.types['builtin_interfaces/msg/Time']
    rng = np.random.default_rng(36)
    pixels = [rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8) for _ in range(CAMERAS)]
    msgtype = 'sensor_msgs/msg/CompressedImage' if jpeg else 'sensor_msgs/msg/Image'
    payloads = [cv2.imencode('.jpg', p)[1].reshape(-1) if jpeg else p.reshape(-1) for p in pixels]

    def message(camera: int, k: int) -> FixtureMessage:
        stamp = EPOCH_NS + k * PERIOD_NS
        head = header(stamp=time_t(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id='cam')
        if jpeg:
            msg: Any = store.types[msgtype](header=head, format='jpeg', data=payloads[camera])
        else:
            msg = store.types[msgtype](
                header=head, height=HEIGHT, width=WIDTH, encoding='rgb8', is_bigendian=0,
                step=WIDTH * 3, data=payloads[camera],
            )  # fmt: skip
        data = bytes(store.serialize_cdr(msg, msgtype))
        return FixtureMessage(stamp + 1_000_000, f'/rig/cam{camera}/image', msgtype, data)

    write_ros2_mcap(
        path,
        (message(c, k) for k in range(frames) for c in range(CAMERAS)),
        compressed=jpeg,
    )
    return path.stat().st_size


def _median(run: Any, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        began = time.perf_counter()
        run()
        times.append(time.perf_counter() - began)
    return statistics.median(times)


def measure(path: Path, repeats: int) -> dict[str, Any]:
    """The pairing's and a decode pass's median seconds over the bag at ``path``."""
    from replaybench.decode import decode_image
    from replaybench.replay.config import InputOptions
    from replaybench.replay.inputs import RunTruth, open_input, replayed
    from replaybench.replay.pairing import pair_inputs
    from replaybench.replay.sync import parse_sync

    inp = open_input(0, path, InputOptions(hash_inputs=False), RunTruth())
    try:
        frames = sum(t.count for t in inp.topics)

        def decode_pass() -> None:
            for raw in replayed(inp):
                decode_image(raw)

        row: dict[str, Any] = {'bag': path.name, 'size_bytes': path.stat().st_size}
        row['frames'] = frames
        row['decode_pass_s'] = _median(decode_pass, repeats)
        for spec in ('exact', 'approx:5'):
            parsed = parse_sync(spec)
            sets = len(pair_inputs([inp], parsed, None).inputs[0].grouping.sets)
            seconds = _median(lambda p=parsed: pair_inputs([inp], p, None), repeats)
            row[f'pair_{spec}_s'] = seconds
            row[f'pair_{spec}_us_per_frame'] = seconds / frames * 1e6
            row[f'pair_{spec}_share_of_decode_pass'] = seconds / row['decode_pass_s']
            row[f'pair_{spec}_sets'] = sets
        return row
    finally:
        inp.source.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m benchmarks.sync_stamps')
    parser.add_argument('--frames', type=int, default=300, help='frames per camera')
    parser.add_argument('--dir', type=Path, default=None, help='where the bags are written')
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--out', type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        for name, jpeg in (('raw', False), ('jpeg', True)):
            bag = Path(tmp) / f'rig_{name}.mcap'
            write_rig_bag(bag, args.frames, jpeg=jpeg)
            load = os.getloadavg()[0]
            row = {'kind': name, 'load_1min': load, **measure(bag, args.repeats)}
            rows.append(row)
            print(
                f'{name}: {row["frames"]} frames, {row["size_bytes"] / 1e6:.0f} MB: pairing '
                f'(exact) {row["pair_exact_s"] * 1e3:.1f} ms '
                f'({row["pair_exact_us_per_frame"]:.1f} us a frame), approx:5 '
                f'{row["pair_approx:5_s"] * 1e3:.1f} ms; a decode pass '
                f'{row["decode_pass_s"] * 1e3:.1f} ms; pairing / decode pass '
                f'{row["pair_exact_share_of_decode_pass"]:.3f} (load {load:.2f})'
            )
    document = {
        'benchmark': 'sync_stamps',
        'date': dt.datetime.now(dt.UTC).isoformat(timespec='seconds'),
        'cameras': CAMERAS,
        'frames_per_camera': args.frames,
        'repeats': args.repeats,
        'python': sys.version.split()[0],
        'rows': rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(document, indent=2) + '\n', encoding='utf-8')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
