"""The real third-party ROS 1 recordings in …/shared/real (see its PROVENANCE.md)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Reader

from replaybench.decode import decode_image, message_kind, probe_topics, to_bgr8
from replaybench.decode._wire import parse_image
from replaybench.types import RawMessage


def first_images(path) -> dict[str, RawMessage]:
    """The first image / compressed-image message of each topic, raw bytes as the bag has them."""
    first: dict[str, RawMessage] = {}
    with Reader(path) as reader:
        for connection, timestamp, raw in reader.messages():
            if connection.topic in first:
                continue
            if message_kind(connection.msgtype) in {'image', 'compressed_image'}:
                first[connection.topic] = RawMessage(
                    connection.topic, connection.msgtype, 'ros1', timestamp, 0, memoryview(raw)
                )
    return first


@pytest.fixture(scope='module')
def bags(real_dir):
    return real_dir / 'bags' / 'ros1'


def test_raw_bag_frames_have_the_documented_shapes(bags):
    frames = {t: decode_image(m) for t, m in first_images(bags / 'ctu_spot_raw.bag').items()}
    summary = {
        t: (d.encoding, d.source_encoding, d.image.shape, str(d.image.dtype), d.is_depth)
        for t, d in frames.items()
    }
    assert summary == {
        '/spot/camera/hand_color/image': ('rgb8', 'rgb8', (480, 640, 3), 'uint8', False),
        '/spot/camera/frontleft/image': ('mono8', 'mono8', (480, 640), 'uint8', False),
        '/spot/camera/hand_mono/image': ('mono8', 'mono8', (171, 224), 'uint8', False),
        '/spot/depth/frontleft/image': ('mono16', '16UC1', (240, 424), 'uint16', True),
    }
    assert int(frames['/spot/depth/frontleft/image'].image.max()) == 4820


def test_big_endian_flagged_rgb8_frame_is_the_unswapped_bytes(bags):
    msg = first_images(bags / 'ctu_spot_raw.bag')['/spot/camera/hand_color/image']
    fields = parse_image(memoryview(msg.data), 'ros1')
    assert (fields.is_bigendian, fields.step, fields.width, fields.height) == (1, 1920, 640, 480)
    raw = np.frombuffer(msg.data, np.uint8, count=fields.size, offset=fields.offset)
    decoded = decode_image(msg)
    np.testing.assert_array_equal(decoded.image, raw.reshape(480, 640, 3))
    assert np.shares_memory(decoded.image, raw)
    # a real photo: the three channels differ (a swap of 8-bit samples would pair them up)
    assert len({int(decoded.image[..., c].sum()) for c in range(3)}) == 3


def test_compressed_bag_frames_decode_as_documented(bags):
    frames = {t: decode_image(m) for t, m in first_images(bags / 'ctu_spot_compressed.bag').items()}
    summary = {
        t: (d.encoding, d.source_encoding, d.image.shape, d.is_depth) for t, d in frames.items()
    }
    assert summary == {
        '/spot/camera/hand_color/image/compressed': ('bgr8', 'jpeg', (480, 640, 3), False),
        '/spot/camera/frontleft/image/compressed': ('mono8', 'jpeg', (480, 640), False),
        '/spot/camera/hand_mono/image/compressed': ('mono8', 'jpeg', (171, 224), False),
        '/spot/depth/frontleft/image/compressed': ('mono16', 'png', (240, 424), True),
    }
    assert frames['/spot/depth/frontleft/image/compressed'].image.dtype == np.uint16


def test_compressed_depth_bag_frame_is_a_240x424_uint16_depth_image(bags):
    frames = first_images(bags / 'ctu_spot_compressedDepth.bag')
    (msg,) = frames.values()
    decoded = decode_image(msg)
    assert (decoded.encoding, decoded.source_encoding, decoded.is_depth) == (
        'mono16', 'compressedDepth', True,
    )  # fmt: skip
    assert decoded.image.shape == (240, 424)
    assert decoded.image.dtype == np.uint16
    assert 0 < int(decoded.image.max()) <= 65535


def test_raw_and_compressed_depth_of_the_same_camera_agree_in_range(bags):
    # the bags hold different instants; the same camera gives the same depth range
    raw = decode_image(first_images(bags / 'ctu_spot_raw.bag')['/spot/depth/frontleft/image'])
    png = decode_image(
        first_images(bags / 'ctu_spot_compressed.bag')['/spot/depth/frontleft/image/compressed']
    )
    assert raw.frame_id == png.frame_id == 'frontleft'
    assert raw.image.shape == png.image.shape


def test_raspicam_jpg_frame_decodes_to_1280x960_bgr(bags):
    (msg,) = first_images(bags / 'ubiquity_aruco_images.bag').values()
    decoded = decode_image(msg)
    assert (decoded.encoding, decoded.source_encoding) == ('bgr8', 'jpeg')
    assert decoded.image.shape == (960, 1280, 3)
    assert decoded.frame_id == 'raspicam'
    assert to_bgr8(decoded.image, decoded.encoding) is decoded.image


def test_to_bgr8_of_every_real_frame_is_a_colour_image(bags):
    for name in ('ctu_spot_raw.bag', 'ctu_spot_compressed.bag', 'ctu_spot_compressedDepth.bag'):
        for msg in first_images(bags / name).values():
            decoded = decode_image(msg)
            bgr = to_bgr8(decoded.image, decoded.encoding)
            assert bgr.shape == (*decoded.image.shape[:2], 3)
            assert bgr.dtype == np.uint8
            assert bgr.max() > 0


def test_real_rgb8_frame_converts_to_the_same_bgr_as_its_jpeg_path(bags):
    # raw rgb8 -> bgr8 via to_bgr8 must put red where OpenCV's own conversion does
    msg = first_images(bags / 'ctu_spot_raw.bag')['/spot/camera/hand_color/image']
    decoded = decode_image(msg)
    np.testing.assert_array_equal(
        to_bgr8(decoded.image, 'rgb8'),
        cv2.cvtColor(np.ascontiguousarray(decoded.image), cv2.COLOR_RGB2BGR),
    )


def test_probe_of_real_sources_when_the_sources_package_is_present(real_dir):
    sources = pytest.importorskip('replaybench.sources')
    open_source = getattr(sources, 'open_source', None)
    if open_source is None:
        pytest.skip('replaybench.sources.open_source not present')
    with open_source(real_dir / 'bags' / 'ros1' / 'ctu_spot_compressedDepth.bag') as source:
        (cam,) = probe_topics(source)
    assert (cam.encoding, cam.width, cam.height, cam.is_depth, cam.error) == (
        'compressedDepth', 424, 240, True, '',
    )  # fmt: skip
    with open_source(real_dir / 'bags' / 'ros1' / 'ubiquity_aruco_images.bag') as source:
        (cam,) = probe_topics(source)
    assert cam.camera_info_topic == '/raspicam_node/camera_info'
    assert (cam.width, cam.height, cam.encoding) == (1280, 960, 'jpeg')
