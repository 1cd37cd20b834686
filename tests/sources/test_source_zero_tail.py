"""Zero-filled tails: after a power loss a file keeps its size but its last part reads as zeros.

Such a file is replayed exactly like one cut short where the zeros begin: every message whose
bytes lie wholly before the zeros is replayed, no message is built from zeroed bytes, and the
source says it is truncated. The bags are written with the real writers (mcap, rosbags); what
is expected is computed from the intact file with the ``mcap`` library / ``rosbags``.
"""

from __future__ import annotations

import bz2
import io
import json
from typing import TYPE_CHECKING

import lz4.frame
import numpy as np
import pytest
import zstandard
from bagtools import TS, image_msg
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore
from typer.testing import CliRunner

from replaybench.cli import app
from replaybench.sources import open_source

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

IMAGE = 'sensor_msgs/msg/Image'
TOPIC = '/cam/image_raw'
T0 = 1_700_000_000 * 1_000_000_000
TS1 = get_typestore(Stores.ROS1_NOETIC)
_COMPRESSION = {'none': CompressionType.NONE, 'zstd': CompressionType.ZSTD}
_COMPRESSION['lz4'] = CompressionType.LZ4


def noise(i: int, width: int = 64, height: int = 48) -> np.ndarray:
    """A frame of noise that never holds a zero byte (90..139), different for every ``i``."""
    rng = np.random.default_rng(1000 + i)
    return rng.integers(90, 140, size=(height, width, 3), dtype=np.uint8)


def cdr_image(i: int, **size: int) -> bytes:
    t = T0 + i * 100_000_000
    return bytes(TS.serialize_cdr(image_msg(t, noise(i, **size)), IMAGE))


def ros1_image(i: int) -> bytes:
    t = T0 + i * 100_000_000
    types = TS1.types
    msg = types[IMAGE](
        header=types['std_msgs/msg/Header'](
            seq=i,
            stamp=types['builtin_interfaces/msg/Time'](sec=t // 10**9, nanosec=t % 10**9),
            frame_id='cam',
        ),
        height=48,
        width=64,
        encoding='rgb8',
        is_bigendian=0,
        step=64 * 3,
        data=noise(i).reshape(-1),
    )
    return bytes(TS1.serialize_ros1(msg, IMAGE))


def write_image_mcap(
    path: Path, compression: str, n: int = 12, chunk_size: int = 20_000, *, chunked: bool = True
) -> list[bytes]:
    """An MCAP of ``n`` noise images on one topic; returns the payloads in log-time order."""
    payloads = [cdr_image(i) for i in range(n)]
    with path.open('wb') as f:
        writer = Writer(
            f, chunk_size=chunk_size, compression=_COMPRESSION[compression], use_chunking=chunked
        )
        writer.start(profile='ros2', library='replaybench-tests')
        text = TS.generate_msgdef(IMAGE, ros_version=2)[0].encode()
        channel = writer.register_channel(
            TOPIC, 'cdr', writer.register_schema(IMAGE, 'ros2msg', text)
        )
        for i, payload in enumerate(payloads):
            t = T0 + i * 100_000_000
            writer.add_message(channel, log_time=t, publish_time=t, data=payload)
        writer.finish()
    return payloads


def write_image_bag(path: Path, compression: str, n: int = 12) -> list[bytes]:
    """A ROS 1 bag of ``n`` noise images, chunks of about two images."""
    payloads = [ros1_image(i) for i in range(n)]
    writer = Writer1(path)
    if compression != 'none':
        writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    writer.chunk_threshold = 15_000
    writer.open()
    conn = writer.add_connection(TOPIC, IMAGE, typestore=TS1)
    for i, payload in enumerate(payloads):
        writer.write(conn, T0 + i * 100_000_000, payload)
    writer.close()
    return payloads


def write_image_rosbag2(path: Path, compression: str, n: int = 14) -> tuple[Path, list[bytes]]:
    """A rosbag2 directory with mcap storage (chunks of about 1 MiB); returns its data file."""
    payloads = [cdr_image(i, width=320, height=240) for i in range(n)]
    writer = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compression != 'none':
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection(TOPIC, IMAGE, typestore=TS)
        for i, payload in enumerate(payloads):
            writer.write(conn, T0 + i * 100_000_000, payload)
    (data_file,) = path.glob('*.mcap')
    return data_file, payloads


def zero_tail(raw: bytes, at: int) -> bytes:
    """``raw`` at full size with every byte from ``at`` on zeroed."""
    return raw[:at] + bytes(len(raw) - at)


def zeros_start(data: bytes) -> int:
    """Where the run of zeros that ends the file begins."""
    return len(data.rstrip(b'\x00'))


def replayed(path: Path) -> tuple[list[bytes], bool, list[str]]:
    with open_source(path) as source:
        got = [bytes(m.data) for m in source.messages()]
        return got, source.truncated, source.warnings


def check_no_invented_frame(got: list[bytes], payloads: list[bytes]) -> None:
    """Every replayed message is one of the written ones, byte for byte, in log-time order."""
    rank = {p: i for i, p in enumerate(payloads)}
    assert all(p in rank for p in got), 'a replayed message is not one that was written'
    assert [rank[p] for p in got] == sorted(rank[p] for p in got)
    assert len(set(got)) == len(got)


def check_reported(truncated: bool, warnings: list[str], zeros_at: int) -> None:
    assert truncated
    assert any(f'byte {zeros_at}' in line and 'zeros' in line for line in warnings), warnings


def tail_offsets(raw: bytes, payloads: list[bytes]) -> list[int]:
    """Inside images (first, middle, last), right after an image, and a few spread points."""
    ends = sorted(raw.find(p) + len(p) for p in payloads if raw.count(p) == 1)
    starts = sorted(raw.find(p) for p in payloads if raw.count(p) == 1)
    points = {len(raw) // 7, len(raw) // 3, len(raw) // 2, 5 * len(raw) // 6, len(raw) - 40}
    if starts:
        points |= {starts[0] + 100, starts[len(starts) // 2] + 3000, starts[-1] + 7000}
        points |= {ends[1], ends[1] + 1, ends[-1] + 2}
    return sorted(p for p in points if 16 < p < len(raw))


# -- uncompressed: exactly the messages before the zeros ---------------------------------------


@pytest.mark.parametrize('chunked', [True, False], ids=['chunked', 'unchunked'])
def test_uncompressed_mcap_with_a_zeroed_tail_replays_exactly_the_messages_before_it(
    tmp_path: Path, chunked: bool
) -> None:
    raw_path = tmp_path / 'whole.mcap'
    payloads = write_image_mcap(raw_path, 'none', chunked=chunked)
    raw = raw_path.read_bytes()
    for at in tail_offsets(raw, payloads):
        damaged = zero_tail(raw, at)
        path = tmp_path / f'zero{at}.mcap'
        path.write_bytes(damaged)
        got, truncated, warnings = replayed(path)
        z = zeros_start(damaged)
        expected = [p for p in payloads if raw.find(p) + len(p) <= z]
        assert got == expected, f'zeros from {at}: {len(got)} replayed, {len(expected)} before'
        check_reported(truncated, warnings, z)


def test_ros1_bag_with_a_zeroed_tail_replays_exactly_the_messages_before_it(
    tmp_path: Path,
) -> None:
    raw_path = tmp_path / 'whole.bag'
    payloads = write_image_bag(raw_path, 'none')
    raw = raw_path.read_bytes()
    index_pos = int.from_bytes(raw[raw.find(b'index_pos=') + 10 :][:8], 'little')
    offsets = [*tail_offsets(raw, payloads), index_pos, index_pos + 1, index_pos + 300]
    for at in sorted(set(offsets)):
        damaged = zero_tail(raw, at)
        path = tmp_path / f'zero{at}.bag'
        path.write_bytes(damaged)
        got, truncated, warnings = replayed(path)
        z = zeros_start(damaged)
        expected = [p for p in payloads if raw.find(p) + len(p) <= z]
        assert got == expected, f'zeros from {at}: {len(got)} replayed, {len(expected)} before'
        check_reported(truncated, warnings, z)


@pytest.mark.parametrize('field', [b'chunk_count=', b'conn_count=', b'index_pos='])
def test_a_bag_zeroed_from_inside_its_header_is_a_cut_bag_not_an_empty_one(
    tmp_path: Path, field: bytes
) -> None:
    raw_path = tmp_path / 'whole.bag'
    write_image_bag(raw_path, 'none')
    raw = raw_path.read_bytes()
    at = raw.find(field) + len(field)  # the field's value and all that follows are zeros
    path = tmp_path / 'zeroed.bag'
    path.write_bytes(zero_tail(raw, at))
    got, truncated, warnings = replayed(path)
    assert got == []
    check_reported(truncated, warnings, zeros_start(zero_tail(raw, at)))


def test_unclosed_ros1_bag_with_a_zeroed_tail_replays_exactly_the_messages_before_it(
    tmp_path: Path,
) -> None:
    payloads = [ros1_image(i) for i in range(9)]
    path = tmp_path / 'open.bag'
    writer = Writer1(path)
    writer.chunk_threshold = 15_000
    writer.open()
    conn = writer.add_connection(TOPIC, IMAGE, typestore=TS1)
    for i, payload in enumerate(payloads):
        writer.write(conn, T0 + i * 100_000_000, payload)
    assert writer.bio is not None
    writer.bio.close()  # killed: no index, the last chunk never written
    writer.bio = None
    raw = path.read_bytes()
    written = [p for p in payloads if p in raw]
    assert 2 < len(written) < len(payloads)
    for at in tail_offsets(raw, written):
        damaged = zero_tail(raw, at)
        path = tmp_path / f'zero{at}.bag'
        path.write_bytes(damaged)
        got, truncated, warnings = replayed(path)
        z = zeros_start(damaged)
        assert got == [p for p in written if raw.find(p) + len(p) <= z], at
        check_reported(truncated, warnings, z)


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_rosbag2_mcap_storage_with_a_zeroed_tail_replays_the_messages_before_it(
    tmp_path: Path, compression: str
) -> None:
    bag = tmp_path / 'bag'
    data_file, payloads = write_image_rosbag2(bag, compression)
    raw = data_file.read_bytes()
    chunks = mcap_chunks(raw)
    assert len(chunks) > 2
    for at in (len(raw) // 4, len(raw) // 2, 4 * len(raw) // 5, len(raw) - 30):
        data_file.write_bytes(zero_tail(raw, at))
        got, truncated, warnings = replayed(bag)
        z = zeros_start(zero_tail(raw, at))
        check_no_invented_frame(got, payloads)
        if compression == 'none':
            assert got == [p for p in payloads if raw.find(p) + len(p) <= z], at
        else:
            whole = set().union(*(messages for end, messages in chunks if end <= z))
            assert whole <= set(got), at
        check_reported(truncated, warnings, z)


# -- compressed chunks: the whole chunks before the zeros, and what decompresses intact ------


def mcap_chunks(raw: bytes) -> list[tuple[int, set[bytes]]]:
    """(file offset where the chunk ends, its message payloads) per chunk, from ``mcap``."""
    summary = make_reader(io.BytesIO(raw)).get_summary()
    assert summary is not None
    out = []
    for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
        stream = io.BytesIO(raw)
        stream.seek(ci.chunk_start_offset + 9)
        records = breakup_chunk(Chunk.read(ReadDataStream(stream)))
        payloads = {bytes(r.data) for r in records if isinstance(r, Message)}
        out.append((ci.chunk_start_offset + ci.chunk_length, payloads))
    return out


def chunk_data_start(raw: bytes) -> int:
    """Where the compressed records of the first chunk begin, from the chunk index."""
    summary = make_reader(io.BytesIO(raw)).get_summary()
    assert summary is not None
    ci = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    return ci.chunk_start_offset + ci.chunk_length - ci.compressed_size


@pytest.mark.parametrize('compression', ['zstd', 'lz4'])
def test_compressed_mcap_with_a_zeroed_tail_replays_every_whole_chunk_before_it(
    tmp_path: Path, compression: str
) -> None:
    raw_path = tmp_path / 'whole.mcap'
    payloads = write_image_mcap(raw_path, compression)
    raw = raw_path.read_bytes()
    chunks = mcap_chunks(raw)
    assert len(chunks) > 3
    for at in sorted({len(raw) * f // 10 for f in range(1, 10)} | {len(raw) - 40}):
        damaged = zero_tail(raw, at)
        path = tmp_path / f'zero{at}.mcap'
        path.write_bytes(damaged)
        got, truncated, warnings = replayed(path)
        z = zeros_start(damaged)
        whole = set().union(*(messages for end, messages in chunks if end <= z))
        assert whole <= set(got), f'zeros from {at}: a whole chunk before them was lost'
        check_no_invented_frame(got, payloads)
        check_reported(truncated, warnings, z)


def prefix_decompressed(compression: str, data: bytes) -> bytes:
    """What the codec's streaming decoder makes of the intact start of a compressed stream."""
    if compression == 'zstd':
        return zstandard.ZstdDecompressor().decompressobj().decompress(data)
    if compression == 'lz4':
        return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data))
    return bz2.BZ2Decompressor().decompress(data)


@pytest.mark.parametrize('compression', ['zstd', 'lz4'])
def test_a_compressed_chunk_running_into_zeros_yields_the_messages_it_holds_intact(
    tmp_path: Path, compression: str
) -> None:
    raw_path = tmp_path / 'one_chunk.mcap'
    payloads = write_image_mcap(raw_path, compression, n=40, chunk_size=1 << 22)
    raw = raw_path.read_bytes()
    (chunk,) = mcap_chunks(raw)
    assert chunk[1] == set(payloads)
    data_start = chunk_data_start(raw)
    for fraction in (0.5, 0.75, 0.95):
        at = data_start + int((chunk[0] - data_start) * fraction)
        damaged = zero_tail(raw, at)
        path = tmp_path / f'zero{at}.mcap'
        path.write_bytes(damaged)
        got, truncated, warnings = replayed(path)
        # The messages whose bytes the codec gives back from the intact compressed prefix.
        intact = prefix_decompressed(compression, damaged[data_start : zeros_start(damaged)])
        expected = [p for p in payloads if p in intact]
        assert expected, 'the intact prefix holds no whole message: the test proves nothing'
        assert got == expected, f'zeros from {fraction:.0%} of the chunk'
        check_reported(truncated, warnings, zeros_start(damaged))


@pytest.mark.parametrize('compression', ['lz4', 'bz2'])
def test_compressed_ros1_bag_with_a_zeroed_tail_replays_every_whole_chunk_before_it(
    tmp_path: Path, compression: str
) -> None:
    raw_path = tmp_path / 'whole.bag'
    payloads = write_image_bag(raw_path, compression)
    raw = raw_path.read_bytes()
    decompress: Callable[[bytes], bytes] = (
        bz2.decompress if compression == 'bz2' else lz4.frame.decompress
    )
    with Reader1(raw_path) as reader:
        chunks = [
            (c.datapos + c.datasize, decompress(raw[c.datapos : c.datapos + c.datasize]))
            for c in reader.chunks.values()
        ]
    assert len(chunks) > 3
    for at in sorted({len(raw) * f // 10 for f in range(1, 10)} | {len(raw) - 40}):
        damaged = zero_tail(raw, at)
        path = tmp_path / f'zero{at}.bag'
        path.write_bytes(damaged)
        got, truncated, warnings = replayed(path)
        z = zeros_start(damaged)
        whole = {p for p in payloads for end, data in chunks if end <= z and p in data}
        assert whole <= set(got), f'zeros from {at}: a whole chunk before them was lost'
        check_no_invented_frame(got, payloads)
        check_reported(truncated, warnings, z)


# -- through the CLI ---------------------------------------------------------------------------


@pytest.mark.parametrize('kind', ['mcap', 'bag'])
def test_a_zeroed_tail_is_reported_on_the_terminal_and_in_run_json_like_a_cut(
    tmp_path: Path, kind: str
) -> None:
    raw_path = tmp_path / f'whole.{kind}'
    if kind == 'mcap':
        payloads = write_image_mcap(raw_path, 'none', chunked=False)
    else:
        payloads = write_image_bag(raw_path, 'none')
    raw = raw_path.read_bytes()
    middle = raw.find(payloads[6]) + len(payloads[6]) // 2  # inside the seventh image
    path = tmp_path / f'zeroed.{kind}'
    path.write_bytes(zero_tail(raw, middle))
    out = tmp_path / 'run'
    result = CliRunner().invoke(
        app, ['run', str(path), '--out', str(out), '--backend', 'null', '--no-report']
    )
    assert result.exit_code == 0, result.output
    run = json.loads((out / 'run.json').read_text())
    (meta,) = run['inputs']
    assert meta['truncated'] is True
    (line,) = [w for w in meta['warnings'] if 'zeros' in w]
    assert f'replaybench: warning: {line}' in result.stderr
    assert run['counts']['frames'] == 6
    assert run['counts']['processed'] == 6
