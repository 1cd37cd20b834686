"""outputs.mcap read by the readers of the robotics toolchain, for every input and output kind.

Inputs: ROS 2 MCAP, Foxglove protobuf MCAP, rosbag2 (sqlite3), ROS 1 bag. Outputs: detections
only, with --annotations, with --annotations --copy-images. Each output is read with

- the mcap reader and the standard decoders (mcap-ros2-support, mcap-protobuf-support),
- rosbags' AnyReader on the file,
- rosbags' rosbag2 reader on the run folder once ``write_rosbag2_metadata`` put a
  metadata.yaml beside the file,

and each must decode every message, agree on the counts per topic with the Statistics record,
and see the messages in non-decreasing log time. The mcap CLI's ``doctor`` rules are checked on
the records themselves (``_doctor``).
"""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, ChunkIndex, MessageIndex, Metadata, Statistics
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from mcap_protobuf.writer import Writer as ProtobufWriter
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.interfaces import ConnectionExtRosbag2
from rosbags.rosbag2 import Reader as Rosbag2Reader
from ruamel.yaml import YAML

from replaybench import msgs
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.sinks import write_rosbag2_metadata
from replaybench.sinks.mcap_writer import OFFERED_QOS_PROFILES

if TYPE_CHECKING:
    from collections.abc import Iterator

BAGS = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags'
FRAMES = 4
BACKENDS = ['hsv', 'null']
OUTPUTS = {
    'detections': {},
    'annotations': {'annotations': True},
    'images': {'annotations': True, 'copy_images': True},
}


def _ros2_messages(path: Path) -> Iterator[tuple[str, int, Any]]:
    with path.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[Ros2DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages():
            yield channel.topic, message.log_time, decoded


def _time(stamp: Any) -> tuple[int, int]:
    return int(stamp.sec), int(stamp.nanosec)


def _protobuf_bag(path: Path) -> Path:
    """The raw and JPEG fixture cameras as Foxglove protobuf (RawImage, CompressedImage and
    CameraCalibration), written with Foxglove's own schemas and mcap-protobuf-support."""
    with path.open('wb') as stream:
        writer = ProtobufWriter(stream)
        for name, prefix in (('rgb8_raw.mcap', '/raw'), ('jpeg.mcap', '/jpeg')):
            for topic, log_time, m in _ros2_messages(BAGS / name):
                if topic.endswith('detections'):
                    continue
                sec, nanosec = _time(m.header.stamp)
                common: dict[str, Any] = {'frame_id': m.header.frame_id}
                if topic.endswith('camera_info'):
                    message: Any = CameraCalibration(
                        width=m.width,
                        height=m.height,
                        distortion_model=m.distortion_model,
                        D=list(m.d),
                        K=list(m.k),
                        R=list(m.r),
                        P=list(m.p),
                        **common,
                    )
                elif topic.endswith('compressed'):
                    message = CompressedImage(data=bytes(m.data), format=m.format, **common)
                else:
                    message = RawImage(
                        width=m.width,
                        height=m.height,
                        encoding=m.encoding,
                        step=m.step,
                        data=bytes(m.data),
                        **common,
                    )
                message.timestamp.seconds, message.timestamp.nanos = sec, nanosec
                writer.write_message(prefix + topic, message, log_time, log_time)
        writer.finish()
    return path


def _input(kind: str, tmp_path: Path) -> Path:
    if kind == 'mcap-protobuf':
        return _protobuf_bag(tmp_path / 'protobuf.mcap')
    return (
        BAGS / {'mcap-ros2': 'rgb8_raw.mcap', 'rosbag2': 'bgr8_rosbag2', 'ros1': 'rgb8.bag'}[kind]
    )


def _image_topics(bag: Path) -> dict[str, int]:
    """Image topics of the input and the frames a run replays of each, by rosbags or mcap."""
    if bag.suffix == '.mcap':
        with bag.open('rb') as stream:
            summary = make_reader(stream).get_summary()
        assert summary is not None
        assert summary.statistics is not None
        counts = {
            summary.channels[c].topic: (summary.schemas[summary.channels[c].schema_id].name, n)
            for c, n in summary.statistics.channel_message_counts.items()
        }
    else:
        with AnyReader([bag]) as reader:
            counts = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
    image_types = {
        msgs.IMAGE,
        msgs.COMPRESSED_IMAGE,
        'foxglove.RawImage',
        'foxglove.CompressedImage',
    }
    return {t: min(n, FRAMES) for t, (msgtype, n) in counts.items() if msgtype in image_types}


def _doctor(path: Path) -> dict[str, int]:
    """The mcap CLI's ``doctor`` rules, checked on the records; the messages per topic."""
    data = path.read_bytes()
    stream = StreamReader(io.BytesIO(data), skip_magic=False, emit_chunks=True, validate_crcs=True)
    records = list(stream.records)
    channels: dict[int, Channel] = {r.id: r for r in records if isinstance(r, Channel)}
    chunks = {}
    offset_of_chunk: dict[int, Chunk] = {}
    # the chunk records at the offsets the chunk indexes give, and what each holds
    indexes = [r for r in records if isinstance(r, ChunkIndex)]
    assert indexes
    for index in indexes:
        reader = StreamReader(
            io.BytesIO(data[index.chunk_start_offset :]), skip_magic=True, emit_chunks=True
        )
        chunk = next(iter(reader.records))
        assert isinstance(chunk, Chunk)
        assert index.chunk_length == len(_serialised(data, index.chunk_start_offset))
        assert (chunk.message_start_time, chunk.message_end_time) == (
            index.message_start_time,
            index.message_end_time,
        )
        assert index.uncompressed_size == chunk.uncompressed_size
        assert index.compressed_size == len(chunk.data)
        offset_of_chunk[index.chunk_start_offset] = chunk
        chunks[index.chunk_start_offset] = index
    counts: dict[int, int] = {}
    last_time = 0
    all_times: list[int] = []
    for start, chunk in offset_of_chunk.items():
        index = chunks[start]
        raw = _decompressed(chunk)
        assert zlib.crc32(raw) == chunk.uncompressed_crc
        # (channel id, log time, offset) of each Message record in the chunk, in order
        messages = []
        position = 0
        while position < len(raw):
            record = _serialised(raw, position)
            if record[0] == 0x05:
                channel_id, _, log_time = struct.unpack_from('<HIQ', record, 9)
                assert channel_id in channels
                messages.append((channel_id, log_time, position))
            position += len(record)
        assert position == len(raw)
        times = [log_time for _, log_time, _ in messages]
        assert (min(times), max(times)) == (chunk.message_start_time, chunk.message_end_time)
        assert times == sorted(times)
        assert times[0] >= last_time
        last_time = times[-1]
        all_times += times
        # each message index record sits where the chunk index says, and lists the channel's
        # messages of the chunk (log time, offset into the uncompressed records) in order
        expected: dict[int, list[tuple[int, int]]] = {}
        for channel_id, log_time, at in messages:
            expected.setdefault(channel_id, []).append((log_time, at))
        assert set(index.message_index_offsets) == set(expected)
        for channel_id, at in index.message_index_offsets.items():
            reader = StreamReader(io.BytesIO(data[at:]), skip_magic=True)
            message_index = next(iter(reader.records))
            assert isinstance(message_index, MessageIndex)
            assert message_index.channel_id == channel_id
            assert message_index.records == expected[channel_id]
        for channel_id, _, _ in messages:
            counts[channel_id] = counts.get(channel_id, 0) + 1
    (stats,) = [r for r in records if isinstance(r, Statistics)]
    assert stats.message_count == sum(counts.values()) == len(all_times)
    assert stats.channel_message_counts == counts
    assert (stats.message_start_time, stats.message_end_time) == (min(all_times), max(all_times))
    assert stats.chunk_count == len(indexes)
    assert stats.channel_count == len(channels)
    assert stats.metadata_count == sum(isinstance(r, Metadata) for r in records)
    assert stats.attachment_count == 0
    by_topic: dict[str, int] = {}
    for channel_id, n in counts.items():
        by_topic[channels[channel_id].topic] = n
    return by_topic


def _serialised(raw: bytes, position: int) -> bytes:
    """The record at ``position`` in a run of records: opcode, u64 length, body."""
    length = int.from_bytes(raw[position + 1 : position + 9], 'little')
    return raw[position : position + 9 + length]


def _decompressed(chunk: Chunk) -> bytes:
    if chunk.compression == 'zstd':
        import zstandard

        return zstandard.ZstdDecompressor().decompress(
            chunk.data, max_output_size=chunk.uncompressed_size
        )
    assert chunk.compression == ''
    return chunk.data


def _expected_topics(bag: Path, output: str) -> dict[str, int]:
    frames = _image_topics(bag)
    expected: dict[str, int] = {}
    for topic, n in frames.items():
        for backend in BACKENDS:
            expected[f'/replaybench/{backend}{topic}/detections'] = n
            if output != 'detections':
                expected[f'/replaybench/{backend}{topic}/annotations'] = n
        if output == 'images':
            expected[topic] = n
    return expected


@pytest.fixture(scope='module')
def outputs() -> dict[tuple[str, str], tuple[Path, Path]]:
    """(input, outputs.mcap) per input kind and output kind, shared by the tests below."""
    return {}


def _run(
    outputs: dict[tuple[str, str], tuple[Path, Path]],
    tmp_path_factory: pytest.TempPathFactory,
    kind: str,
    out: str,
) -> tuple[Path, Path]:
    key = (kind, out)
    if key not in outputs:
        base = tmp_path_factory.mktemp(f'{kind}-{out}')
        bag = _input(kind, base)
        run_benchmark(
            RunConfig(
                inputs=[bag],
                backends=BACKENDS,
                out_dir=base / 'run',
                max_frames=FRAMES,
                report=False,
                **OUTPUTS[out],  # type: ignore[arg-type]
            )
        )
        outputs[key] = (bag, base / 'run' / 'outputs.mcap')
    return outputs[key]


KINDS = ['mcap-ros2', 'mcap-protobuf', 'rosbag2', 'ros1']


@pytest.mark.parametrize('out', list(OUTPUTS))
@pytest.mark.parametrize('kind', KINDS)
def test_every_reader_decodes_every_message_and_the_counts_agree(
    outputs: dict[tuple[str, str], tuple[Path, Path]],
    tmp_path_factory: pytest.TempPathFactory,
    kind: str,
    out: str,
) -> None:
    bag, path = _run(outputs, tmp_path_factory, kind, out)
    expected = _expected_topics(bag, out)
    camera_infos = {t for t in _doctor(path) if t.endswith('camera_info')}
    assert camera_infos  # the CameraInfo of the replayed camera, also without --copy-images

    # mcap reader with the standard decoder of each channel's encoding
    with path.open('rb') as stream:
        reader = make_reader(
            stream, decoder_factories=[Ros2DecoderFactory(), ProtobufDecoderFactory()]
        )
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None
        assert summary.statistics is not None
        by_mcap: dict[str, int] = {}
        times = []
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert decoded is not None
            assert schema is not None
            assert (schema.encoding, channel.message_encoding) == ('ros2msg', 'cdr')
            assert channel.metadata['offered_qos_profiles'] == OFFERED_QOS_PROFILES
            assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
            by_mcap[channel.topic] = by_mcap.get(channel.topic, 0) + 1
            times.append(message.log_time)
    assert header.profile == 'ros2'
    assert times == sorted(times)  # in file order: non-decreasing log time across channels
    stats = {
        summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()
    }
    doctor = _doctor(path)
    assert by_mcap == stats == doctor
    assert {t: n for t, n in by_mcap.items() if t not in camera_infos} == expected

    # rosbags on the file: every channel is listed and deserialises
    with AnyReader([path]) as bag_reader:
        listed = {c.topic: c.msgcount for c in bag_reader.connections}
        by_rosbags: dict[str, int] = {}
        for connection, _, data in bag_reader.messages():
            bag_reader.deserialize(data, connection.msgtype)
            by_rosbags[connection.topic] = by_rosbags.get(connection.topic, 0) + 1
    assert listed == by_rosbags == by_mcap

    # rosbags' rosbag2 reader on the run folder with a metadata.yaml
    write_rosbag2_metadata(path)
    folder = path.parent
    with Rosbag2Reader(folder) as rosbag2:
        assert rosbag2.message_count == sum(by_mcap.values())
        assert {t: info.msgcount for t, info in rosbag2.topics.items()} == by_mcap
        exts = [c.ext for c in rosbag2.connections]
        assert all(isinstance(e, ConnectionExtRosbag2) and e.offered_qos_profiles for e in exts)
        assert [t for _, t, _ in rosbag2.messages()] == sorted(times)
    with AnyReader([folder]) as directory:
        by_directory: dict[str, int] = {}
        for connection, _, data in directory.messages():
            directory.deserialize(data, connection.msgtype)
            by_directory[connection.topic] = by_directory.get(connection.topic, 0) + 1
    assert by_directory == by_mcap


@pytest.mark.parametrize('kind', KINDS)
def test_copied_images_decode_to_the_input_stamps_and_sizes(
    outputs: dict[tuple[str, str], tuple[Path, Path]],
    tmp_path_factory: pytest.TempPathFactory,
    kind: str,
) -> None:
    bag, path = _run(outputs, tmp_path_factory, kind, 'images')
    from replaybench.decode import decode_image
    from replaybench.sources import open_source

    with open_source(bag) as source:
        topics = list(_image_topics(bag))
        want = {}
        for raw in source.messages(topics=topics):
            if raw.seq < FRAMES:
                frame = decode_image(raw)
                want[(raw.topic, raw.log_time_ns)] = (frame.stamp_ns, frame.image.shape)
    got = {}
    with AnyReader([path]) as reader:
        connections = [c for c in reader.connections if c.topic in topics]
        assert {c.msgtype for c in connections} <= {msgs.IMAGE, msgs.COMPRESSED_IMAGE}
        for connection, log_time, data in reader.messages(connections):
            message: Any = reader.deserialize(data, connection.msgtype)
            sec, nanosec = _time(message.header.stamp)
            if connection.msgtype == msgs.IMAGE:
                shape = (message.height, message.width, message.step // message.width)
            else:
                import cv2
                import numpy as np

                image = cv2.imdecode(np.asarray(message.data), cv2.IMREAD_UNCHANGED)
                assert image is not None
                shape = image.shape
            got[(connection.topic, log_time)] = (sec * 10**9 + nanosec, shape)
    assert got == want


def test_a_rerun_writes_a_byte_identical_file(tmp_path: Path) -> None:
    config = {
        'inputs': [BAGS / 'two_camera.mcap'],
        'backends': ['hsv', 'null'],
        'report': False,
        'annotations': True,
        'copy_images': True,
    }
    first = run_benchmark(RunConfig(out_dir=tmp_path / 'a', **config))  # type: ignore[arg-type]
    second = run_benchmark(RunConfig(out_dir=tmp_path / 'b', **config))  # type: ignore[arg-type]
    assert first.run_dir is not None
    assert second.run_dir is not None
    data = (first.run_dir / 'outputs.mcap').read_bytes()
    assert data == (second.run_dir / 'outputs.mcap').read_bytes()
    assert len(data) > 10_000


def test_the_rosbag2_record_and_metadata_yaml_describe_the_same_bag(tmp_path: Path) -> None:
    outcome = run_benchmark(
        RunConfig(
            inputs=[BAGS / 'jpeg.mcap'],
            backends=['hsv'],
            out_dir=tmp_path / 'run',
            report=False,
            annotations=True,
        )
    )
    assert outcome.run_dir is not None
    path = outcome.run_dir / 'outputs.mcap'
    with path.open('rb') as stream:
        (record,) = list(make_reader(stream).iter_metadata())
    assert record.name == 'rosbag2'
    yaml = YAML(typ='safe')
    embedded = yaml.load(record.metadata['serialized_metadata'])
    written = yaml.load(write_rosbag2_metadata(path).read_text())['rosbag2_bagfile_information']
    assert embedded == written
    assert embedded['version'] == 8
    assert embedded['message_count'] == 30  # 10 camera infos, 10 detections, 10 annotations
    topics = {t['topic_metadata']['name']: t for t in embedded['topics_with_message_count']}
    annotations = topics['/replaybench/hsv/camera/image_raw/compressed/annotations']
    assert annotations['topic_metadata']['type'] == msgs.IMAGE_ANNOTATIONS
    assert annotations['message_count'] == 10


def test_metadata_yaml_is_refused_for_an_mcap_with_a_protobuf_channel(tmp_path: Path) -> None:
    bag = _protobuf_bag(tmp_path / 'protobuf.mcap')
    with pytest.raises(ValueError, match=r'channel /raw/camera/\S+ is protobuf, not cdr'):
        write_rosbag2_metadata(bag)
    assert not (tmp_path / 'metadata.yaml').exists()
