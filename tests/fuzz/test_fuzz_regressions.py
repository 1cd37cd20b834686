"""Minimal reproducers of the failures the hostile-input tests found, one per fix."""

from __future__ import annotations

import struct
import tracemalloc

import cv2
import numpy as np
import pytest
from fuzz.fuzzkit import (
    bag_image_fields,
    cleanup,
    edit_db3,
    fixture_bytes,
    mcap_message_ends,
    mcap_records,
    put_uint,
    replay,
    rewrite_mcap,
    write_case,
)
from rosbags.typesys import Stores, get_typestore

from replaybench.decode import decode_image
from replaybench.errors import DecodeError
from replaybench.results.records import read_frames_csv
from replaybench.sources import open_source
from replaybench.sources.mcap import mcap_payload
from replaybench.sources.rosbag1 import ros1_payload
from replaybench.types import RawMessage

STORE = get_typestore(Stores.ROS2_HUMBLE)


def compressed_message(payload: bytes, fmt: str) -> RawMessage:
    types = STORE.types
    msg = types['sensor_msgs/msg/CompressedImage'](
        header=types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='cam'
        ),
        format=fmt,
        data=np.frombuffer(payload, np.uint8),
    )
    data = bytes(STORE.serialize_cdr(msg, 'sensor_msgs/msg/CompressedImage'))
    return RawMessage('/cam/compressed', 'sensor_msgs/msg/CompressedImage', 'cdr', 1, 0, data)


def jpeg_claiming(width: int, height: int) -> bytes:
    ok, buf = cv2.imencode('.jpg', np.full((24, 32, 3), 128, np.uint8))
    assert ok
    jpeg = bytearray(buf.tobytes())
    sof = jpeg.index(b'\xff\xc0')
    struct.pack_into('>HH', jpeg, sof + 5, height, width)
    return bytes(jpeg)


def test_jpeg_header_claiming_a_huge_image_is_rejected_before_decoding():
    # Before the fix OpenCV allocated (and filled) the claimed 32000x8192x3 bytes: ~750 MiB
    # for a 700-byte payload.
    msg = compressed_message(jpeg_claiming(32_000, 8_192), 'rgb8; jpeg compressed bgr8')
    tracemalloc.start()
    try:
        with pytest.raises(DecodeError, match='pixels per byte'):
            decode_image(msg)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 << 20


def test_png_header_claiming_a_huge_image_is_rejected_before_decoding():
    ok, buf = cv2.imencode('.png', np.zeros((24, 32), np.uint8))
    assert ok
    png = bytearray(buf.tobytes())
    struct.pack_into('>II', png, 16, 16_000, 16_000)
    with pytest.raises(DecodeError, match='pixels per byte'):
        decode_image(compressed_message(bytes(png), 'mono8; png compressed mono8'))


def test_large_plausible_jpeg_still_decodes():
    # 2100 x 2100 is above the size decoded unconditionally; a real payload is large enough.
    ramp = np.linspace(0, 255, 2100, dtype=np.float32)
    image = np.broadcast_to(ramp[None, :, None], (2100, 2100, 3)).astype(np.uint8)
    image = image + np.random.default_rng(0).integers(0, 8, image.shape, dtype=np.uint8)
    ok, buf = cv2.imencode('.jpg', image)
    assert ok
    decoded = decode_image(compressed_message(buf.tobytes(), 'bgr8; jpeg compressed bgr8'))
    assert decoded.image.shape == (2100, 2100, 3)


def test_black_full_hd_jpeg_decodes_whatever_its_size():
    ok, buf = cv2.imencode('.jpg', np.zeros((1080, 1920, 3), np.uint8))
    assert ok
    decoded = decode_image(compressed_message(buf.tobytes(), 'bgr8; jpeg compressed bgr8'))
    assert decoded.image.shape == (1080, 1920, 3)


def test_mcap_message_index_offset_with_the_top_bit_set_skips_only_that_message(tmp_path):
    # Before the fix the offset became negative (int64) and the payload lookup indexed the
    # mapped file from its end: IndexError out of the source.
    name = 'rgb8_raw.mcap'
    data = fixture_bytes(name)
    image_index = next(
        r for r in mcap_records(name) if r.op == 0x07 and r.fields['channel_id'].value == 2
    )
    first_entry = image_index.body['entries'][0]
    data = put_uint(data, first_entry + 8, 8, 2**64 - 2**40)
    case = write_case(tmp_path, {name: data})
    with open_source(case / name) as source:
        images = [m for m in source.messages() if m.topic == '/camera/image_raw']
        warnings = source.warnings
    assert len(images) == 9
    assert any('unreadable message' in w for w in warnings)
    outcome = replay(case / name, tmp_path)
    assert outcome.code == 0
    assert len([r for r in outcome.rows if r['topic'] == '/camera/image_raw']) == 9
    cleanup(case, outcome.out)


def test_ros1_payload_at_a_negative_position_is_none():
    assert ros1_payload(memoryview(bytes(64)), -100) is None
    assert mcap_payload(memoryview(bytes(64)), -100) is None


def negative_time_db3(tmp_path):
    db3 = tmp_path / 'negative.db3'
    db3.write_bytes(fixture_bytes('bgr8_rosbag2/bgr8_rosbag2.db3'))
    edit_db3(db3, [('UPDATE messages SET timestamp = -5 - id WHERE id <= 3', ())])
    return db3


def test_rosbag2_negative_timestamps_are_replayed_at_log_time_zero(tmp_path):
    db3 = negative_time_db3(tmp_path)
    with open_source(db3) as source:
        times = [m.log_time_ns for m in source.messages()]
        assert all(ns >= 0 for t in source.topics() for ns in (t.first_ns, t.last_ns))
        warnings = source.warnings
    assert len(times) == 30
    assert times[:3] == [0, 0, 0]
    assert times == sorted(times)
    assert any('negative timestamps' in w for w in warnings)


def test_rosbag2_negative_timestamps_do_not_break_the_outputs_mcap(tmp_path):
    # Before the fix the negative log time reached the detections MCAP writer: struct.error.
    db3 = negative_time_db3(tmp_path)
    case = write_case(tmp_path, {db3.name: db3.read_bytes()})
    outcome = replay(case / db3.name, tmp_path)
    assert outcome.code == 0, outcome.stderr
    assert len(outcome.rows) == 10
    cleanup(case, outcome.out)


def test_run_with_an_image_topic_but_no_complete_image_exits_cleanly(tmp_path):
    """The image channel is declared but the file is cut before its first image ends.

    ``cli._print_summary`` raised TypeError on an empty summary (fixed in the CLI since).
    """
    data = fixture_bytes('rgb8_raw.mcap')
    first_image_end = next(end for t, end in mcap_message_ends('rgb8_raw.mcap') if 'image' in t)
    case = write_case(tmp_path, {'cut.mcap': data[: first_image_end - 1]})
    outcome = replay(case / 'cut.mcap', tmp_path)
    assert outcome.rows == []
    cleanup(case, outcome.out)


def test_bag_image_stamped_after_2038_replays_into_the_outputs_mcap(tmp_path):
    """A ROS 1 stamp is u32 seconds; ROS 2 Time.sec is int32.

    Reported to the lead: ``msgs.serialize_detections`` raised struct.error for such stamps.
    """
    data = fixture_bytes('rgb8.bag')
    fields = bag_image_fields(data)[0]
    data = put_uint(data, fields['sec'].pos, 4, 2**31 + 5)
    case = write_case(tmp_path, {'late.bag': data})
    outcome = replay(case / 'late.bag', tmp_path)
    assert outcome.code == 0, outcome.stderr
    assert len(outcome.rows) == 10
    cleanup(case, outcome.out)


def test_image_topic_longer_than_a_file_name_replays(tmp_path):
    """Reported to the lead: the sample image's file name is built from the whole topic name,
    so a 300-character topic raised OSError (file name too long) after the replay."""
    topic = '/' + 'x' * 300

    def channel(_cid, name, encoding, schema_id):
        return (topic if name == '/camera/image_raw' else name), encoding, schema_id

    data = rewrite_mcap(fixture_bytes('rgb8_raw.mcap'), channel=channel)
    case = write_case(tmp_path, {'long.mcap': data})
    outcome = replay(case / 'long.mcap', tmp_path, report=True)
    assert outcome.code == 0, outcome.stderr
    assert {r['topic'] for r in outcome.rows} == {topic}
    cleanup(case, outcome.out)


def test_image_topic_with_a_carriage_return_replays_and_reads_back(tmp_path):
    """Found by ``make fuzz``: a topic named ``'\\r'`` was written unquoted into frames.csv, so
    the report could not read the file back and the run failed after run.json said complete.
    frames.csv now holds it escaped (``\\r``, no raw CR) and reads back as ``'\\r'``."""

    def channel(cid, name, encoding, schema_id):
        return ('\r' if cid == 2 else name), encoding, schema_id

    data = rewrite_mcap(fixture_bytes('two_camera.mcap'), channel=channel, compression='zstd')
    case = write_case(tmp_path, {'cr.mcap': data})
    outcome = replay(case / 'cr.mcap', tmp_path, backends=('null', 'hsv'), report=True)
    assert outcome.code == 0, outcome.stderr
    assert '\\r' in {r['topic'] for r in outcome.rows}
    assert '\r' in {r.topic for r in read_frames_csv(outcome.out / 'frames.csv')}
    cleanup(case, outcome.out)
