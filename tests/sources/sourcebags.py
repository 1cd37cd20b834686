"""Bags for the source tests, written with the real writers (mcap, rosbags).

A *plan* is the list of messages in write order: (topic, log_time_ns, text). Payloads are
std_msgs/String messages whose text is unique, so every payload can be found in the file.
``expected_order`` states the contract independently of the readers: log time, then topic,
then write order; ``seq`` numbers each topic's messages in that order.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import NamedTuple

from mcap.writer import CompressionType, IndexType, Writer
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

from replaybench.sources.mcap import McapSource

TS2 = get_typestore(Stores.ROS2_HUMBLE)
TS1 = get_typestore(Stores.ROS1_NOETIC)
STRING = 'std_msgs/msg/String'
MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000

Plan = list[tuple[str, int, str]]


class Expected(NamedTuple):
    topic: str
    log_time_ns: int
    seq: int
    payload: bytes


def tie_plan(n: int = 30) -> Plan:
    """Two topics share every log time (``/b`` written before ``/a``); ``/c/slow`` is sparse;
    ``/a`` has two messages with one log time; a block of log times is written out of order."""
    steps = list(range(n))
    steps[10:20] = steps[15:20] + steps[10:15]
    plan: Plan = []
    for i in steps:
        t = T0 + i * 10 * MS
        plan.append(('/b', t, f'/b#{i}' + 'x' * (i % 7 * 13)))
        plan.append(('/a', t, f'/a#{i}' + 'y' * (i % 5 * 17)))
        if i % 4 == 0:
            plan.append(('/c/slow', t + 5 * MS, f'/c#{i}'))
        if i == n // 2:
            plan.append(('/a', t, f'/a#{i}-second'))
    return plan


def cdr(text: str) -> bytes:
    return bytes(TS2.serialize_cdr(TS2.types[STRING](data=text), STRING))


def ros1(text: str) -> bytes:
    return bytes(TS1.serialize_ros1(TS1.types[STRING](data=text), STRING))


def expected_order(plan: Plan, encode: object = cdr) -> list[Expected]:
    assert callable(encode)
    ranked = sorted(enumerate(plan), key=lambda x: (x[1][1], x[1][0], x[0]))
    seq: dict[str, int] = {}
    out = []
    for _, (topic, t, text) in ranked:
        n = seq.get(topic, 0)
        seq[topic] = n + 1
        out.append(Expected(topic, t, n, encode(text)))
    return out


def as_expected(messages: object) -> list[Expected]:
    """What a source yielded, in the same shape (payload copied to bytes)."""
    assert hasattr(messages, '__iter__')
    return [Expected(m.topic, m.log_time_ns, m.seq, bytes(m.data)) for m in messages]


_COMPRESSION = {
    'none': CompressionType.NONE,
    'zstd': CompressionType.ZSTD,
    'lz4': CompressionType.LZ4,
}


def write_mcap(
    path: Path,
    plan: Plan,
    compression: str = 'none',
    chunk_size: int = 1 << 20,
    *,
    indexed: bool = True,
    chunked: bool = True,
    schema_name: str = STRING,
    message_encoding: str = 'cdr',
    schema_encoding: str = 'ros2msg',
) -> Path:
    """A ros2 MCAP of the plan (CDR std_msgs/String, unless told otherwise)."""
    extra: dict[str, object] = {}
    if not indexed:
        extra = {
            'index_types': IndexType.NONE,
            'repeat_channels': False,
            'repeat_schemas': False,
            'use_statistics': False,
            'use_summary_offsets': False,
        }
    with path.open('wb') as f:
        writer = Writer(
            f,
            chunk_size=chunk_size,
            compression=_COMPRESSION[compression],
            use_chunking=chunked,
            **extra,  # type: ignore[arg-type]
        )
        writer.start(profile='ros2', library='replaybench-tests')
        text = TS2.generate_msgdef(STRING, ros_version=2)[0].encode()
        schema = writer.register_schema(schema_name, schema_encoding, text)
        channels: dict[str, int] = {}
        for topic, t, msg in plan:
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, message_encoding, schema)
            writer.add_message(channels[topic], log_time=t, publish_time=t, data=cdr(msg))
        writer.finish()
    return path


def write_bag(
    path: Path,
    plan: Plan,
    compression: str = 'none',
    chunk_threshold: int = 1 << 20,
    *,
    close: bool = True,
    two_connections: bool = False,
) -> Path:
    """A ROS 1 bag of the plan; ``close=False`` leaves it unindexed like a killed recorder.

    ``two_connections`` publishes ``/a`` through two connections (two caller ids), alternating.
    """
    writer = Writer1(path)
    if compression != 'none':
        writer.set_compression(Writer1.CompressionFormat[compression.upper()])
    writer.chunk_threshold = chunk_threshold
    writer.open()
    conns: dict[str, object] = {}
    extra = None
    uses = 0
    for topic, t, msg in plan:
        if topic not in conns:
            conns[topic] = writer.add_connection(topic, STRING, typestore=TS1, callerid='/node1')
            if topic == '/a' and two_connections:
                extra = writer.add_connection(topic, STRING, typestore=TS1, callerid='/node2')
        conn = conns[topic]
        if topic == '/a' and extra is not None:
            uses += 1
            conn = extra if uses % 2 == 0 else conn
        writer.write(conn, t, ros1(msg))  # type: ignore[arg-type]
    if close:
        writer.close()
    else:
        assert writer.bio is not None
        writer.bio.close()
        writer.bio = None
    return path


def write_rosbag2(
    path: Path,
    plan: Plan,
    storage: str = 'sqlite3',
    compression: str = 'none',
) -> Path:
    """A rosbag2 directory of the plan (compression: none, message or file, zstd)."""
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    writer = Writer2(path, version=9, storage_plugin=plugin)
    if compression != 'none':
        writer.set_compression(CompressionMode[compression.upper()], CompressionFormat.ZSTD)
    with writer:
        conns: dict[str, object] = {}
        for topic, t, msg in plan:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, STRING, typestore=TS2)
            writer.write(conns[topic], t, cdr(msg))  # type: ignore[arg-type]
    return path


def write_split_rosbag2(path: Path, plans: list[Plan], storage: str = 'sqlite3') -> Path:
    """One rosbag2 directory whose messages are split over several data files."""
    path.mkdir()
    yaml = YAML(typ='safe')
    names: list[str] = []
    metas = []
    for i, part in enumerate(plans):
        part_dir = write_rosbag2(path.parent / f'{path.name}.part{i}', part, storage)
        meta = yaml.load((part_dir / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        (data_file,) = [Path(x) for x in meta['relative_file_paths']]
        name = f'{path.name}_{i}{data_file.suffix}'
        shutil.move(part_dir / data_file.name, path / name)
        shutil.rmtree(part_dir)
        names.append(name)
        metas.append(meta)
    info = metas[0]
    counts: dict[str, int] = {}
    for meta in metas:
        for topic in meta['topics_with_message_count']:
            name = topic['topic_metadata']['name']
            counts[name] = counts.get(name, 0) + topic['message_count']
    for topic in info['topics_with_message_count']:
        topic['message_count'] = counts[topic['topic_metadata']['name']]
    info['relative_file_paths'] = names
    info['message_count'] = sum(m['message_count'] for m in metas)
    info['files'] = [
        {**meta['files'][0], 'path': name} for meta, name in zip(metas, names, strict=True)
    ]
    with (path / 'metadata.yaml').open('w') as f:
        YAML(typ='safe').dump({'rosbag2_bagfile_information': info}, f)
    return path


def write_mixed_mcap(path: Path, compression: CompressionType) -> Path:
    """An MCAP of chunks holding one, two or three channels, some with 64 or more messages of
    a channel (read in place) and most with a few (gathered), log times out of file order
    across chunks, and one channel in an encoding that cannot be read."""
    with path.open('wb') as f:
        writer = Writer(f, chunk_size=2048, compression=compression)
        writer.start(profile='', library='tests')
        schema = writer.register_schema(name='std_msgs/String', encoding='ros2msg', data=b'')
        channels = [
            writer.register_channel(topic=f'/t{i}', message_encoding='cdr', schema_id=schema)
            for i in range(3)
        ]
        odd = writer.register_channel(topic='/odd', message_encoding='json', schema_id=0)
        t = 1_000_000_000
        for block in range(60):
            burst = 80 if block % 17 == 0 else 1 + block % 4
            for i in range(burst):
                channel = channels[(block + i) % (1 + block % 3)]
                stamp = t + (block * 7919 + i * 104729) % 5_000_000
                writer.add_message(channel, stamp, bytes([block, i % 256]) * 8, stamp)
            if block % 5 == 0:
                writer.add_message(odd, t, b'{}', t)
        writer.finish()
    return path


def read_source(path: Path) -> tuple[object, ...]:
    """Everything an MCAP source says: its messages, a window of one topic, its topics,
    skipped topics, warnings and whether it is cut."""
    with McapSource(path) as source:
        messages = [(m.topic, m.log_time_ns, m.seq, bytes(m.data)) for m in source.messages()]
        windowed = [(m.topic, m.seq) for m in source.messages(['/t1'], 1_001_000_000)]
        return (
            messages,
            windowed,
            source.topics(),
            source.skipped_topics(),
            source.warnings,
            source.truncated,
        )
