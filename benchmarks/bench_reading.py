"""Item a: reading frames with replaybench against mcap's and rosbags' readers.

Each pass opens the bag and iterates every message. replaybench decodes each message to an
image array and reads its first pixel; mcap (``make_reader(f).iter_messages()``) reads the
first byte of each message's data; rosbags (``AnyReader`` + CDR deserialisation) reads the
first byte of each deserialised ``Image.data``.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING

from benchmarks.core import ItemResult, Sampler, interleaved, per_second, ratio

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from benchmarks.core import Check, Context, Measurement
    from benchmarks.data import Bag
    from replaybench.sources import Source

__all__ = [
    'BAGS',
    'ITEM',
    'READERS',
    'decode_all',
    'read_mcap',
    'read_replaybench',
    'reader_sampler',
    'run',
]

ITEM = 'a'
#: Bags of the suite this item reads.
BAGS: tuple[str, ...] = ('raw', 'zstd')

#: Speed-up over each baseline reader on uncompressed chunks, and on zstd chunks.
_TARGET_RAW = 10.0
_TARGET_ZSTD = 1.0


def decode_all(source: Source) -> int:
    """Decode every message of an opened source and read one pixel; the number of frames."""
    from replaybench.decode import decode_image

    frames = 0
    for msg in source.messages():
        decode_image(msg).image.item(0)
        frames += 1
    return frames


def read_replaybench(path: Path) -> int:
    """``open_source(path).messages()`` + ``decode_image`` per message."""
    from replaybench.sources import open_source

    with open_source(path) as source:
        return decode_all(source)


def read_mcap(path: Path) -> int:
    """mcap's raw iteration: ``make_reader(f).iter_messages()``."""
    from mcap.reader import make_reader

    frames = 0
    with path.open('rb') as f:
        for _schema, _channel, message in make_reader(f).iter_messages():
            message.data[0]
            frames += 1
    return frames


def read_rosbags(path: Path) -> int:
    """rosbags' ``AnyReader`` with its CDR deserialisation."""
    from rosbags.highlevel import AnyReader

    frames = 0
    with AnyReader([path]) as reader:
        for connection, _timestamp, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            message.data[0]  # type: ignore[attr-defined]
            frames += 1
    return frames


READERS: dict[str, Callable[[Path], int]] = {
    'replaybench': read_replaybench,
    'mcap': read_mcap,
    'rosbags': read_rosbags,
}


def reader_sampler(reader: str, bag: Bag) -> Sampler:
    """Frames per second of one reader over one bag (open + read every frame)."""
    return Sampler(
        f'read[{reader}, {bag.spec.name}]',
        'frames/s',
        per_second(partial(READERS[reader], bag.path)),
        bag.spec.frames,
    )


def _bag_checks(ctx: Context, bag: Bag, measurements: list[Measurement]) -> list[Check]:
    names = list(READERS)  # replaybench first
    ours, *baselines = interleaved(
        [reader_sampler(reader, bag) for reader in names], ctx.settings.repeats
    )
    measurements += [ours, *baselines]
    target = _TARGET_ZSTD if bag.spec.compression else _TARGET_RAW
    return [
        ratio(ITEM, f'read+decode vs {name} [{bag.spec.name}]', ours, theirs, target)
        for name, theirs in zip(names[1:], baselines, strict=True)
    ]


def run(ctx: Context) -> ItemResult:
    measurements: list[Measurement] = []
    checks: list[Check] = []
    for name in ('raw', 'zstd'):
        checks += _bag_checks(ctx, ctx.bags[name], measurements)
    notes = [
        'Each pass opens the bag and reads every frame; page cache warm.',
        (
            'replaybench reads one pixel of each decoded array; mcap one byte of Message.data; '
            'rosbags one byte of the deserialised Image.data.'
        ),
    ]
    return ItemResult(
        ITEM, 'Reading: source + decode vs mcap / rosbags', measurements, checks, notes
    )
