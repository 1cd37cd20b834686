"""CameraInfo decoding (CDR + ROS 1), camera_info topic matching and the nearest-stamp index."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from replaybench.decode import CameraInfoIndex, camera_info_topic_for, decode_camera_info
from replaybench.errors import DecodeError
from replaybench.types import CameraInfo, RawMessage, Serialization

K = [612.5, 0.0, 320.25, 0.0, 611.75, 240.5, 0.0, 0.0, 1.0]
R = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
P = [612.5, 0.0, 320.25, -3.5, 0.0, 611.75, 240.5, 0.0, 0.0, 0.0, 1.0, 0.0]
D = [0.11, -0.22, 0.001, -0.002, 0.05]


def camera_info_message(
    mk,
    serialization: Serialization,
    stamp_ns: int,
    *,
    topic: str = '/cam/camera_info',
    log_time: int = 0,
) -> RawMessage:
    store = mk.stores[serialization]
    roi = store.types['sensor_msgs/msg/RegionOfInterest'](
        x_offset=4, y_offset=6, height=100, width=200, do_rectify=True
    )
    arrays = {
        'd': np.array(D),
        'k': np.array(K),
        'r': np.array(R),
        'p': np.array(P),
    }
    if serialization == 'ros1':
        arrays = {name.upper(): value for name, value in arrays.items()}
    msg = store.types['sensor_msgs/msg/CameraInfo'](
        header=mk.header(serialization, stamp_ns, 'cam_optical'),
        height=480,
        width=640,
        distortion_model='plumb_bob',
        binning_x=2,
        binning_y=3,
        roi=roi,
        **arrays,
    )
    raw = mk.serialize(serialization, msg, 'sensor_msgs/msg/CameraInfo')
    return RawMessage(topic, 'sensor_msgs/msg/CameraInfo', serialization, log_time, 0, raw)


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
def test_camera_info_decodes_from_both_serialisations(mk, serialization):
    msg = camera_info_message(mk, serialization, 1_600_000_000_500_000_000, log_time=77)
    info = decode_camera_info(msg)
    assert info == CameraInfo(
        stamp_ns=1_600_000_000_500_000_000,
        frame_id='cam_optical',
        width=640,
        height=480,
        distortion_model='plumb_bob',
        d=tuple(D),
        k=tuple(K),
        r=tuple(R),
        p=tuple(P),
        binning_x=2,
        binning_y=3,
        roi=(4, 6, 100, 200, True),
        log_time_ns=77,
        topic='/cam/camera_info',
    )
    assert all(type(v) is float for v in info.k)


@pytest.mark.parametrize('serialization', ['cdr', 'ros1'])
def test_broken_camera_info_raises_decode_error(mk, serialization):
    msg = camera_info_message(mk, serialization, 1)
    with pytest.raises(DecodeError, match='CameraInfo'):
        decode_camera_info(msg._replace(data=msg.data[:50]))
    with pytest.raises(DecodeError, match='not a camera info'):
        decode_camera_info(msg._replace(msgtype='sensor_msgs/msg/Image'))


@pytest.mark.parametrize(
    ('image_topic', 'expected'),
    [
        ('/cam/image_raw', '/cam/camera_info'),
        ('/cam/image_raw/compressed', '/cam/camera_info'),
        ('/cam/image_rect_color', '/cam/camera_info'),
        ('/spot/depth/frontleft/image/compressedDepth', '/spot/depth/frontleft/camera_info'),
        ('/spot/depth/frontleft/image', '/spot/depth/frontleft/camera_info'),
        ('/stereo/left/image/theora', '/stereo/left/camera_info'),
        ('/stereo/right/image_raw/zstd', '/stereo/right/camera_info'),
        ('/image_raw', '/camera_info'),
        ('stereo/left/image_raw', '/stereo/left/camera_info'),
        ('/other/image_raw', None),
    ],
)
def test_camera_info_topic_is_found_in_the_image_namespace(image_topic, expected):
    candidates = [
        '/cam/camera_info',
        '/spot/depth/frontleft/camera_info',
        '/stereo/left/camera_info',
        '/stereo/right/camera_info',
        '/camera_info',
    ]
    assert camera_info_topic_for(image_topic, candidates) == expected


def test_a_single_camera_info_topic_is_used_only_for_a_single_camera():
    # one camera (raw + compressed of it), one camera_info topic somewhere else: use it
    images = ['/raspicam_node/image', '/raspicam_node/image/compressed']
    assert (
        camera_info_topic_for('/raspicam_node/image/compressed', ['/calib/camera_info'], images)
        == '/calib/camera_info'
    )
    # two cameras: guessing could pair depth with colour intrinsics
    images = ['/camera/color/image_raw', '/camera/depth/image_rect_raw']
    assert camera_info_topic_for(images[1], ['/calib/camera_info'], images) is None
    assert camera_info_topic_for(images[1], ['/camera/color/camera_info'], images) is None
    assert (
        camera_info_topic_for(images[0], ['/camera/color/camera_info'], images)
        == '/camera/color/camera_info'
    )
    # two candidates, no namespace match
    assert camera_info_topic_for('/x/image', ['/a/camera_info', '/b/camera_info']) is None


def info(stamp_ns: int, topic: str = '/cam/camera_info', width: int = 640) -> CameraInfo:
    return CameraInfo(stamp_ns, 'f', width, 480, 'plumb_bob', (), (), (), (), topic=topic)


def found(index: CameraInfoIndex, topic: str, stamp_ns: int) -> CameraInfo:
    """The index's CameraInfo for an image on ``topic`` at ``stamp_ns``; one must be found."""
    got = index.lookup(topic, stamp_ns)
    assert got is not None, (topic, stamp_ns)
    return got


def test_lookup_returns_the_nearest_stamp_and_the_earlier_one_on_a_tie():
    index = CameraInfoIndex(
        [info(300, width=3), info(100, width=1), info(200, width=2)], ['/cam/image_raw']
    )
    width = lambda stamp: found(index, '/cam/image_raw', stamp).width  # noqa: E731
    assert width(0) == 1
    assert width(100) == 1
    assert width(149) == 1
    assert width(150) == 1  # tie -> earlier
    assert width(151) == 2
    assert width(250) == 2  # tie -> earlier
    assert width(251) == 3
    assert width(10**12) == 3
    assert index.lookup('/elsewhere/image_raw', 100) is None
    assert len(index) == 3
    assert [i.width for i in index.all()] == [3, 1, 2]
    assert index.topics() == ['/cam/camera_info']


def test_lookup_keeps_cameras_apart():
    index = CameraInfoIndex(
        [info(100, '/left/camera_info', 1), info(100, '/right/camera_info', 2)],
        ['/left/image_raw', '/right/image_raw'],
    )
    assert found(index, '/left/image_raw/compressed', 100).width == 1
    assert found(index, '/right/image_raw', 100).width == 2
    assert CameraInfoIndex().lookup('/left/image_raw', 100) is None


def test_index_from_a_source_reads_every_camera_info_and_skips_broken_ones(mk):
    good = [
        camera_info_message(mk, 'cdr', stamp, log_time=stamp + 5) for stamp in (3_000, 1_000, 2_000)
    ]
    broken = good[0]._replace(data=good[0].data[:20], log_time_ns=9_999)
    image = mk.simple(np.zeros((4, 4), np.uint8), 'cdr', 'mono8')._replace(topic='/cam/image_raw')
    source = mk.source([*good, broken, image])
    index = CameraInfoIndex.from_source(source, ['/cam/camera_info'])
    assert len(index) == 3
    assert index.skipped == 1
    assert [i.log_time_ns for i in index.all()] == [1_005, 2_005, 3_005]
    assert found(index, '/cam/image_raw/compressed', 2_400).stamp_ns == 2_000
    assert CameraInfoIndex.from_source(source, []).lookup('/cam/image_raw', 0) is None


def test_real_ros1_camera_info_decodes(real_dir):
    from rosbags.rosbag1 import Reader

    infos = []
    with Reader(real_dir / 'bags' / 'ros1' / 'ubiquity_aruco_images.bag') as reader:
        for connection, timestamp, raw in reader.messages():
            if connection.msgtype == 'sensor_msgs/msg/CameraInfo':
                msg = RawMessage(connection.topic, connection.msgtype, 'ros1', timestamp, 0, raw)
                infos.append(decode_camera_info(msg))
    assert len(infos) == 15
    first = infos[0]
    assert (first.width, first.height, first.distortion_model) == (1280, 960, 'plumb_bob')
    assert first.frame_id == 'raspicam'
    assert (round(first.k[0], 1), round(first.k[4], 1)) == (1014.3, 1011.7)
    assert len(first.d) == 5
    assert len(first.p) == 12


def test_real_rosbag2_camera_info_decodes_the_same_as_ros1(real_dir):
    from mcap.reader import make_reader
    from rosbags.rosbag1 import Reader

    ros1 = []
    with Reader(real_dir / 'bags' / 'ros1' / 'ubiquity_aruco_images.bag') as reader:
        for connection, timestamp, raw in reader.messages():
            if connection.msgtype == 'sensor_msgs/msg/CameraInfo':
                msg = RawMessage(connection.topic, connection.msgtype, 'ros1', timestamp, 0, raw)
                ros1.append(decode_camera_info(msg))
    path = next((real_dir / 'derived' / 'ubiquity_aruco_images_rosbag2_mcap').glob('*.mcap'))
    cdr = []
    with path.open('rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema is not None
            if schema.name == 'sensor_msgs/msg/CameraInfo':
                msg = RawMessage(
                    channel.topic, schema.name, 'cdr', message.log_time, 0, message.data
                )
                cdr.append(decode_camera_info(msg))
    assert len(cdr) == len(ros1) == 15
    for a, b in zip(cdr, ros1, strict=True):
        assert (a.stamp_ns, a.k, a.d, a.p, a.r) == (b.stamp_ns, b.k, b.d, b.p, b.r)


@pytest.mark.parametrize(
    'relative',
    [
        'bags/ros1/ubiquity_aruco_images.bag',
        'derived/ubiquity_aruco_images_rosbag2_mcap',
        'derived/ubiquity_aruco_images_foxglove_protobuf.mcap',
    ],
)
def test_index_from_real_sources_pairs_the_raspicam_image_with_its_info(real_dir, relative):
    sources = pytest.importorskip('replaybench.sources')
    open_source = getattr(sources, 'open_source', None)
    if open_source is None:
        pytest.skip('replaybench.sources.open_source not present')
    with open_source(real_dir / relative) as source:
        index = CameraInfoIndex.from_source(source, ['/raspicam_node/camera_info'])
    assert len(index) == 15
    assert index.skipped == 0
    stamps = sorted(i.stamp_ns for i in index.all())
    image_stamp = 1_491_682_360_314_066_469  # header stamp of the one image (PROVENANCE)
    nearest = min(stamps, key=lambda s: (abs(s - image_stamp), s))
    found = index.lookup('/raspicam_node/image/compressed', image_stamp)
    assert found is not None
    assert found.stamp_ns == nearest
    assert (found.width, found.height) == (1280, 960)


_FLOATS = st.floats(allow_nan=False, width=64)


@pytest.mark.parametrize(
    ('serialization', 'little_endian'), [('cdr', True), ('cdr', False), ('ros1', True)]
)
@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    frame_id=st.text(max_size=9),
    model=st.sampled_from(['', 'plumb_bob', 'rational_polynomial', 'equidistant']),
    d=st.lists(_FLOATS, max_size=14),
    kr=st.lists(_FLOATS, min_size=30, max_size=30),
    sizes=st.lists(st.integers(0, 2**32 - 1), min_size=8, max_size=8),
    do_rectify=st.booleans(),
    stamp=st.integers(0, 2**31 * 1_000_000_000 - 1),
)
def test_camera_info_reads_as_the_rosbags_deserialiser_reads_it(
    mk, serialization, little_endian, frame_id, model, d, kr, sizes, do_rectify, stamp
):
    store = mk.stores[serialization]
    roi = store.types['sensor_msgs/msg/RegionOfInterest'](
        x_offset=sizes[4], y_offset=sizes[5], height=sizes[6], width=sizes[7], do_rectify=do_rectify
    )
    arrays = {'d': np.array(d), 'k': np.array(kr[:9]), 'r': np.array(kr[9:18])}
    arrays['p'] = np.array(kr[18:30])
    if serialization == 'ros1':
        arrays = {name.upper(): value for name, value in arrays.items()}
    msg = store.types['sensor_msgs/msg/CameraInfo'](
        header=mk.header(serialization, stamp, frame_id),
        height=sizes[0],
        width=sizes[1],
        distortion_model=model,
        binning_x=sizes[2],
        binning_y=sizes[3],
        roi=roi,
        **arrays,
    )
    raw = mk.serialize(serialization, msg, 'sensor_msgs/msg/CameraInfo', little_endian)
    info = decode_camera_info(
        RawMessage('/c/camera_info', 'sensor_msgs/msg/CameraInfo', serialization, 5, 0, raw)
    )
    if serialization == 'ros1':
        back = store.deserialize_ros1(raw, 'sensor_msgs/msg/CameraInfo')
        dd, k, r, p = back.D, back.K, back.R, back.P
    else:
        back = store.deserialize_cdr(raw, 'sensor_msgs/msg/CameraInfo')
        dd, k, r, p = back.d, back.k, back.r, back.p
    assert (info.frame_id, info.height, info.width) == (
        back.header.frame_id,
        back.height,
        back.width,
    )
    assert info.stamp_ns == back.header.stamp.sec * 1_000_000_000 + back.header.stamp.nanosec
    assert info.distortion_model == back.distortion_model
    assert (info.d, info.k, info.r, info.p) == tuple(tuple(map(float, a)) for a in (dd, k, r, p))
    assert (info.binning_x, info.binning_y) == (back.binning_x, back.binning_y)
    assert info.roi == (
        back.roi.x_offset,
        back.roi.y_offset,
        back.roi.height,
        back.roi.width,
        back.roi.do_rectify,
    )
