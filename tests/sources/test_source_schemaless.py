"""MCAP files whose summary lists the channels but holds no Schema records.

The ``mcap`` writer with ``repeat_schemas=False`` (rosbag2's ``noRepeatedSchemas``) writes the
schemas only where they were registered, in the data section (inside a chunk when chunking is
on). The channels' message types are then read from there.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from bagtools import TS, image_msg, noise_frames
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from typer.testing import CliRunner

from replaybench.cli import app
from replaybench.sources import open_source

if TYPE_CHECKING:
    import io
    from pathlib import Path

IMAGE = 'sensor_msgs/msg/Image'
INFO = 'sensor_msgs/msg/CameraInfo'
T0 = 1_700_000_000 * 1_000_000_000
STEP = 100_000_000
_COMPRESSION = {'none': CompressionType.NONE, 'zstd': CompressionType.ZSTD}
_COMPRESSION['lz4'] = CompressionType.LZ4


def image_payloads(n: int) -> list[bytes]:
    return [
        bytes(TS.serialize_cdr(image_msg(T0 + i * STEP, frame), IMAGE))
        for i, frame in enumerate(noise_frames(n))
    ]


def info_payload(i: int) -> bytes:
    types = TS.types
    msg = types[INFO](
        header=types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=i, nanosec=0), frame_id='cam'
        ),
        height=48,
        width=64,
        distortion_model='plumb_bob',
        d=np.zeros(5),
        k=np.zeros(9),
        r=np.zeros(9),
        p=np.zeros(12),
        binning_x=0,
        binning_y=0,
        roi=types['sensor_msgs/msg/RegionOfInterest'](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        ),
    )
    return bytes(TS.serialize_cdr(msg, INFO))


def writer_for(f: io.BufferedWriter, compression: str, *, chunked: bool = True) -> Writer:
    writer = Writer(
        f,
        chunk_size=20_000,
        compression=_COMPRESSION[compression],
        use_chunking=chunked,
        repeat_schemas=False,
    )
    writer.start(profile='ros2', library='replaybench-tests')
    return writer


def register(writer: Writer, topic: str, msgtype: str) -> int:
    text = TS.generate_msgdef(msgtype, ros_version=2)[0].encode()
    return writer.register_channel(topic, 'cdr', writer.register_schema(msgtype, 'ros2msg', text))


def check_schemaless(path: Path) -> None:
    """The file is what the tests mean: channels in the summary, no schemas there."""
    with path.open('rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert summary.channels
    assert not summary.schemas


def write_images(path: Path, compression: str, n: int, *, chunked: bool = True) -> list[bytes]:
    payloads = image_payloads(n)
    with path.open('wb') as f:
        writer = writer_for(f, compression, chunked=chunked)
        channel = register(writer, '/cam/image_raw', IMAGE)
        for i, payload in enumerate(payloads):
            t = T0 + i * STEP
            writer.add_message(channel, log_time=t, publish_time=t, data=payload)
        writer.finish()
    check_schemaless(path)
    return payloads


def run_cli(path: Path, out: Path) -> dict[str, Any]:
    result = CliRunner().invoke(
        app, ['run', str(path), '--out', str(out), '--backend', 'null', '--no-report']
    )
    assert result.exit_code == 0, result.output
    run: dict[str, Any] = json.loads((out / 'run.json').read_text())
    return run


@pytest.mark.parametrize(
    ('compression', 'chunked'),
    [('none', True), ('zstd', True), ('lz4', True), ('none', False)],
    ids=['uncompressed', 'zstd', 'lz4', 'unchunked'],
)
def test_an_mcap_without_schemas_in_its_summary_replays_every_frame(
    tmp_path: Path, compression: str, chunked: bool
) -> None:
    path = tmp_path / 'noschemas.mcap'
    payloads = write_images(path, compression, 8, chunked=chunked)
    with open_source(path) as source:
        (topic,) = source.topics()
        got = list(source.messages())
        assert not source.truncated
    assert (topic.name, topic.msgtype, topic.count) == ('/cam/image_raw', IMAGE, 8)
    assert [bytes(m.data) for m in got] == payloads
    assert {m.msgtype for m in got} == {IMAGE}
    run = run_cli(path, tmp_path / 'run')
    assert (run['counts']['frames'], run['counts']['processed']) == (8, 8)


def test_a_schema_first_written_in_a_later_chunk_is_found(tmp_path: Path) -> None:
    path = tmp_path / 'late.mcap'
    payloads = image_payloads(10)
    with path.open('wb') as f:
        writer = writer_for(f, 'zstd')
        images = register(writer, '/cam/image_raw', IMAGE)
        info = None
        for i, payload in enumerate(payloads):
            t = T0 + i * STEP
            writer.add_message(images, log_time=t, publish_time=t, data=payload)
            if i == 6:  # several chunks after the first
                info = register(writer, '/cam/camera_info', INFO)
            if info is not None:
                writer.add_message(info, log_time=t, publish_time=t, data=info_payload(i))
        writer.finish()
    check_schemaless(path)
    with path.open('rb') as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        first_chunk = min(ci.chunk_start_offset for ci in summary.chunk_indexes)
        info_id = next(c.id for c in summary.channels.values() if c.topic == '/cam/camera_info')
        info_chunks = [ci for ci in summary.chunk_indexes if info_id in ci.message_index_offsets]
        assert min(ci.chunk_start_offset for ci in info_chunks) > first_chunk
    with open_source(path) as source:
        types = {t.name: (t.msgtype, t.count) for t in source.topics()}
        got = list(source.messages())
    assert types == {'/cam/camera_info': (INFO, 4), '/cam/image_raw': (IMAGE, 10)}
    assert {(m.topic, m.msgtype) for m in got} == {
        ('/cam/camera_info', INFO),
        ('/cam/image_raw', IMAGE),
    }


def test_a_protobuf_channel_gets_its_descriptor_from_the_data_section(tmp_path: Path) -> None:
    descriptor = b'\x0a\x10fake-descriptor'
    path = tmp_path / 'pb.mcap'
    with path.open('wb') as f:
        writer = Writer(f, compression=CompressionType.ZSTD, repeat_schemas=False)
        writer.start(profile='', library='tests')
        schema = writer.register_schema('foxglove.RawImage', 'protobuf', descriptor)
        channel = writer.register_channel('/cam', 'protobuf', schema)
        writer.add_message(channel, log_time=5, publish_time=5, data=b'\x08\x01')
        writer.finish()
    check_schemaless(path)
    with open_source(path) as source:
        (msg,) = source.messages()
    assert (msg.msgtype, msg.serialization, msg.schema) == (
        'foxglove.RawImage',
        'protobuf',
        descriptor,
    )


def test_a_channel_whose_schema_is_nowhere_in_the_file_is_reported(tmp_path: Path) -> None:
    path = tmp_path / 'missing.mcap'
    with path.open('wb') as f:
        writer = writer_for(f, 'none')
        channel = writer.register_channel('/cam/image_raw', 'cdr', 7)  # no schema 7 anywhere
        writer.add_message(channel, log_time=T0, publish_time=T0, data=image_payloads(1)[0])
        writer.finish()
    with open_source(path) as source:
        (topic,) = source.topics()
        warnings = source.warnings
    assert topic.msgtype == ''
    assert any('/cam/image_raw' in line and 'schema 7' in line for line in warnings), warnings


def test_rosbag2_mcap_storage_without_schemas_in_its_summary_replays_every_frame(
    tmp_path: Path,
) -> None:
    bag = tmp_path / 'bag'
    payloads = image_payloads(6)
    writer2 = Writer2(bag, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer2:
        conn = writer2.add_connection('/cam/image_raw', IMAGE, typestore=TS)
        for i, payload in enumerate(payloads):
            writer2.write(conn, T0 + i * STEP, payload)
    (data_file,) = bag.glob('*.mcap')
    # The same messages written again as rosbag2's recorder does with noRepeatedSchemas.
    with data_file.open('rb') as f:
        reader = make_reader(f)
        messages = [(c.topic, s, m) for s, c, m in reader.iter_messages()]
    with data_file.open('wb') as f:
        writer = writer_for(f, 'zstd')
        channels: dict[str, int] = {}
        for topic, schema, message in messages:
            if topic not in channels:
                assert schema is not None
                sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                channels[topic] = writer.register_channel(topic, 'cdr', sid)
            writer.add_message(
                channels[topic],
                log_time=message.log_time,
                publish_time=message.log_time,
                data=message.data,
            )
        writer.finish()
    check_schemaless(data_file)
    with open_source(bag) as source:
        assert source.format == 'rosbag2'
        assert [bytes(m.data) for m in source.messages()] == payloads
    run = run_cli(bag, tmp_path / 'run')
    assert (run['counts']['frames'], run['counts']['processed']) == (6, 6)
