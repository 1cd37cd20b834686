"""The real recordings in shared/real (see its PROVENANCE.md); skipped when absent."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from replaybench.sources import open_source

if TYPE_CHECKING:
    from pathlib import Path

IMAGE = 'sensor_msgs/msg/Image'
COMPRESSED = 'sensor_msgs/msg/CompressedImage'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
SPOT = [
    '/spot/camera/frontleft/image',
    '/spot/camera/hand_color/image',
    '/spot/camera/hand_mono/image',
    '/spot/depth/frontleft/image',
]
ARUCO = {'/raspicam_node/camera_info': 15, '/raspicam_node/image/compressed': 1}

# path under shared/real -> (format, serialization, {topic: (msgtype, count)})
EXPECTED: dict[str, tuple[str, str, dict[str, tuple[str, int]]]] = {
    'bags/ros1/ctu_spot_raw.bag': ('rosbag1', 'ros1', dict.fromkeys(SPOT, (IMAGE, 1))),
    'bags/ros1/ctu_spot_compressed.bag': (
        'rosbag1',
        'ros1',
        {f'{t}/compressed': (COMPRESSED, 1) for t in SPOT},
    ),
    'bags/ros1/ctu_spot_compressedDepth.bag': (
        'rosbag1',
        'ros1',
        {'/spot/depth/frontleft/image/compressedDepth': (COMPRESSED, 1)},
    ),
    'bags/ros1/ubiquity_aruco_images.bag': (
        'rosbag1',
        'ros1',
        {
            '/raspicam_node/camera_info': (CAMERA_INFO, 15),
            '/raspicam_node/image/compressed': (COMPRESSED, 1),
        },
    ),
    'derived/ctu_spot_raw_rosbag2_sqlite3': ('rosbag2', 'cdr', dict.fromkeys(SPOT, (IMAGE, 1))),
    'derived/ctu_spot_compressed_rosbag2_mcap': (
        'rosbag2',
        'cdr',
        {f'{t}/compressed': (COMPRESSED, 1) for t in SPOT},
    ),
    'derived/ubiquity_aruco_images_rosbag2_mcap': (
        'rosbag2',
        'cdr',
        {
            '/raspicam_node/camera_info': (CAMERA_INFO, 15),
            '/raspicam_node/image/compressed': (COMPRESSED, 1),
        },
    ),
    'derived/ctu_spot_raw_foxglove_protobuf.mcap': (
        'mcap',
        'protobuf',
        dict.fromkeys(SPOT, ('foxglove.RawImage', 1)),
    ),
    'derived/ctu_spot_compressed_foxglove_protobuf.mcap': (
        'mcap',
        'protobuf',
        {f'{t}/compressed': ('foxglove.CompressedImage', 1) for t in SPOT},
    ),
    'derived/ubiquity_aruco_images_foxglove_protobuf.mcap': (
        'mcap',
        'protobuf',
        {
            '/raspicam_node/camera_info': ('foxglove.CameraCalibration', 15),
            '/raspicam_node/image/compressed': ('foxglove.CompressedImage', 1),
        },
    ),
}


def _reference(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic, log time, payload) as the upstream readers give them."""
    if path.suffix == '.mcap':
        with path.open('rb') as f:
            return sorted(
                (channel.topic, message.log_time, message.data)
                for _, channel, message in make_reader(f).iter_messages()
            )
    with AnyReader([path]) as reader:
        return sorted((c.topic, t, bytes(d)) for c, t, d in reader.messages())


@pytest.mark.parametrize('name', sorted(EXPECTED))
def test_real_recordings_open_with_their_documented_topics(shared_real: Path, name: str) -> None:
    fmt, serialization, topics = EXPECTED[name]
    path = shared_real / name
    if not path.exists():
        pytest.skip(f'{path} not present')
    with open_source(path) as source:
        infos = source.topics()
        messages = list(source.messages())
        assert (source.format, source.truncated, source.warnings) == (fmt, False, [])
        assert all(f.is_file() and f.stat().st_size > 0 for f in source.files)
    assert {t.name: (t.msgtype, t.count) for t in infos} == topics
    assert {t.serialization for t in infos} == {serialization}
    assert sorted((m.topic, m.log_time_ns, bytes(m.data)) for m in messages) == _reference(path)
    keys = [(m.log_time_ns, m.topic) for m in messages]
    assert keys == sorted(keys)
    for info in infos:
        times = [m.log_time_ns for m in messages if m.topic == info.name]
        assert (info.first_ns, info.last_ns) == (times[0], times[-1])
        assert [m.seq for m in messages if m.topic == info.name] == list(range(info.count))
    if serialization == 'protobuf':
        assert all(m.schema and m.msgtype.startswith('foxglove.') for m in messages)


def test_real_ros1_image_payload_deserialises_to_the_documented_frame(shared_real: Path) -> None:
    path = shared_real / 'bags/ros1/ctu_spot_raw.bag'
    if not path.exists():
        pytest.skip(f'{path} not present')
    store = get_typestore(Stores.ROS1_NOETIC)
    with open_source(path) as source:
        (msg,) = source.messages(topics=['/spot/camera/hand_color/image'])
        image: Any = store.deserialize_ros1(bytes(msg.data), msg.msgtype)
    assert (image.width, image.height, image.encoding, image.step) == (640, 480, 'rgb8', 1920)
    assert image.is_bigendian == 1
    assert len(image.data) == 640 * 480 * 3


def test_derived_containers_hold_the_same_pixels_as_the_ros1_bag(shared_real: Path) -> None:
    bag = shared_real / 'bags/ros1/ctu_spot_raw.bag'
    db3 = shared_real / 'derived/ctu_spot_raw_rosbag2_sqlite3'
    if not (bag.exists() and db3.exists()):
        pytest.skip('ctu_spot_raw recordings not present')
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    ros2 = get_typestore(Stores.ROS2_HUMBLE)
    with open_source(bag) as a, open_source(db3) as b:
        for m1, m2 in zip(a.messages(), b.messages(), strict=True):
            assert (m1.topic, m1.log_time_ns, m1.msgtype) == (m2.topic, m2.log_time_ns, m2.msgtype)
            i1: Any = ros1.deserialize_ros1(bytes(m1.data), m1.msgtype)
            i2: Any = ros2.deserialize_cdr(bytes(m2.data), m2.msgtype)
            assert (i1.width, i1.height, i1.encoding) == (i2.width, i2.height, i2.encoding)
            assert i1.data.tobytes() == i2.data.tobytes()


@pytest.mark.parametrize('fraction', [0.1, 0.35, 0.6, 0.85, 0.999])
def test_a_cut_real_bag_replays_every_complete_message(
    shared_real: Path, tmp_path: Path, fraction: float
) -> None:
    path = shared_real / 'bags/ros1/ubiquity_aruco_images.bag'
    if not path.exists():
        pytest.skip(f'{path} not present')
    raw = path.read_bytes()
    reference = _reference(path)
    ends = {data: raw.find(data) + len(data) for _, _, data in reference}
    assert all(raw.count(data) == 1 for data in ends)
    cut = int(len(raw) * fraction)
    cut_path = tmp_path / 'cut.bag'
    cut_path.write_bytes(raw[:cut])
    with open_source(cut_path) as source:
        got = [(m.topic, m.log_time_ns, bytes(m.data)) for m in source.messages()]
        assert source.truncated
    assert sorted(got) == [r for r in reference if ends[r[2]] <= cut]
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)
