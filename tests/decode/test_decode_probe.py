"""probe_topics: camera topics, their first frame, depth flags and camera_info pairing."""

from __future__ import annotations

import struct
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest

from replaybench.decode import CameraTopic, probe_topics

if TYPE_CHECKING:
    from replaybench.types import RawMessage


def png(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode('.png', image)
    assert ok
    return buf.tobytes()


def at(msg: RawMessage, topic: str, log_time_ns: int) -> RawMessage:
    return msg._replace(topic=topic, log_time_ns=log_time_ns)


def test_probe_describes_each_camera_topic_from_its_first_frame(mk):
    colour = mk.simple(np.zeros((30, 40, 3), np.uint8), 'cdr', 'rgb8')
    depth = mk.simple(np.ones((24, 32), np.uint16), 'cdr', '16UC1')
    jpeg_like = mk.compressed('cdr', png(np.zeros((6, 8), np.uint8)), 'mono8; png compressed ')
    info = mk.simple(np.zeros((1, 1), np.uint8), 'cdr', 'mono8')._replace(
        msgtype='sensor_msgs/msg/CameraInfo'
    )
    source = mk.source(
        [
            at(colour, '/cam/color/image_raw', 10),
            at(colour, '/cam/color/image_raw', 30),
            at(colour, '/cam/color/image_raw', 50),
            at(depth, '/cam/depth/image_rect_raw', 20),
            at(jpeg_like, '/cam/ir/image/compressed', 25),
            at(info, '/cam/color/camera_info', 11),
            at(info, '/cam/ir/camera_info', 12),
        ]
    )
    found = probe_topics(source)
    assert found == [
        CameraTopic('/cam/color/image_raw', 'sensor_msgs/msg/Image', 'image', 3, 10, 50,
                    'rgb8', 40, 30, False, '/cam/color/camera_info', ''),
        CameraTopic('/cam/depth/image_rect_raw', 'sensor_msgs/msg/Image', 'image', 1, 20, 20,
                    '16UC1', 32, 24, True, None, ''),
        CameraTopic('/cam/ir/image/compressed', 'sensor_msgs/msg/CompressedImage',
                    'compressed_image', 1, 25, 25, 'png', 8, 6, False, '/cam/ir/camera_info', ''),
    ]  # fmt: skip


def test_a_topic_whose_first_frame_fails_reports_the_reason(mk):
    broken = mk.image('ros1', np.zeros(10, np.uint8), width=4, height=4, step=4, encoding='mono8')
    weird = mk.image('ros1', np.zeros(16, np.uint8), width=4, height=4, step=4, encoding='xyz9')
    source = mk.source([at(broken, '/a/image', 1), at(weird, '/b/image', 2)])
    a, b = probe_topics(source)
    assert (a.encoding, a.width, a.height, a.is_depth) == ('?', 0, 0, False)
    assert 'needs 16' in a.error
    assert b.encoding == '?'
    assert "'xyz9'" in b.error


def test_undecodable_compressed_depth_is_still_flagged_as_depth(mk):
    rvl = struct.pack('<iff', 0, 0, 0) + b'\x07' * 64
    by_format = mk.compressed('cdr', rvl, '16UC1; compressedDepth rvl')
    source = mk.source(
        [
            at(by_format, '/d/image_raw/compressed', 1),  # only the format says depth
            at(by_format._replace(data=by_format.data[:30]), '/e/image/compressedDepth', 2),
        ]
    )
    d, e = probe_topics(source)
    assert d.is_depth
    assert 'RVL' in d.error
    assert e.is_depth
    assert 'truncated' in e.error


def test_probe_reads_only_the_first_message_of_each_topic(mk):
    colour = mk.simple(np.zeros((3, 4, 3), np.uint8), 'cdr', 'bgr8')
    messages = [at(colour, '/x/image', i) for i in range(50)]

    listed = mk.source(messages)
    yielded = []

    class CountingSource:
        def topics(self):
            return listed.topics()

        def messages(self, topics=None, start_ns=None, end_ns=None):
            for m in listed.messages(topics, start_ns, end_ns):
                yielded.append(m)
                yield m

    (cam,) = probe_topics(CountingSource())
    assert cam.count == 50
    assert len(yielded) == 1


REAL_FILES = {
    'bags/ros1/ctu_spot_raw.bag': 'rgb8',
    'derived/ctu_spot_raw_rosbag2_sqlite3': 'rgb8',
    'derived/ctu_spot_raw_foxglove_protobuf.mcap': 'rgb8',
    'bags/ros1/ctu_spot_compressed.bag': 'jpeg',
    'derived/ctu_spot_compressed_rosbag2_mcap': 'jpeg',
    'derived/ctu_spot_compressed_foxglove_protobuf.mcap': 'jpeg',
}


@pytest.mark.parametrize('relative', sorted(REAL_FILES))
def test_probe_of_every_real_container_finds_the_spot_cameras(real_dir, relative):
    sources = pytest.importorskip('replaybench.sources')
    open_source = getattr(sources, 'open_source', None)
    if open_source is None:
        pytest.skip('replaybench.sources.open_source not present')
    with open_source(real_dir / relative) as source:
        cams = {c.name.removesuffix('/compressed'): c for c in probe_topics(source)}
    assert all(c.error == '' for c in cams.values()), cams
    hand = cams['/spot/camera/hand_color/image']
    assert (hand.encoding, hand.width, hand.height, hand.is_depth) == (
        REAL_FILES[relative], 640, 480, False,
    )  # fmt: skip
    mono = cams['/spot/camera/hand_mono/image']
    assert (mono.width, mono.height) == (224, 171)
    depth = cams['/spot/depth/frontleft/image']
    assert (depth.width, depth.height, depth.is_depth) == (424, 240, True)
    assert all(c.camera_info_topic is None for c in cams.values())  # these bags have none
