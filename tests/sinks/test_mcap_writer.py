from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader

from replaybench.sinks.mcap_writer import DetectionsWriter, detections_channel
from replaybench.types import CameraInfo, Detection

if TYPE_CHECKING:
    from pathlib import Path

T0 = 1_700_000_000_000_000_000
INFO = CameraInfo(
    stamp_ns=T0 - 5,
    frame_id='camera_optical_frame',
    width=320,
    height=240,
    distortion_model='plumb_bob',
    d=(0.0,) * 5,
    k=(277.0, 0.0, 160.0, 0.0, 277.0, 120.0, 0.0, 0.0, 1.0),
    r=(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
    p=(277.0, 0.0, 160.0, 0.0, 0.0, 277.0, 120.0, 0.0, 0.0, 0.0, 1.0, 0.0),
)
RED = Detection(0, 'red', 0.9, 10.0, 20.0, 30.0, 60.0)
BLUE = Detection(2, 'blue', 0.25, 100.5, 0.0, 120.0, 10.0)


def _write_run(path: Path) -> None:
    with DetectionsWriter(path) as writer:
        writer.add_camera_info('/camera/camera_info', T0 + 1, INFO)
        writer.add('hsv', '/camera/image_raw', T0 + 2, T0 - 5, 'camera_optical_frame', [RED, BLUE])
        writer.add('yolo-nano', '/camera/image_raw', T0 + 3, T0 - 5, 'camera_optical_frame', [BLUE])
        writer.add('hsv', '/camera/image_raw', T0 + 40, T0 + 30, 'camera_optical_frame', [])
        writer.add('yolo-nano', '/camera/image_raw', T0 + 41, T0 + 30, 'camera_optical_frame', [])


def _boxes(message: Any) -> list[tuple[str, float, float, float, float, float]]:
    out = []
    for det in message.detections:
        hyp = det.results[0].hypothesis
        cx, cy = det.bbox.center.position.x, det.bbox.center.position.y
        w, h = det.bbox.size_x, det.bbox.size_y
        out.append((hyp.class_id, hyp.score, cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2))
    return out


def _expected(*dets: Detection) -> list[tuple[str, float, float, float, float, float]]:
    return [(d.label, d.score, d.x0, d.y0, d.x1, d.y1) for d in dets]


def test_detections_channel_replaces_dashes_in_the_backend_label() -> None:
    assert detections_channel('yolo-nano-v2', '/cam/image_raw') == (
        '/replaybench/yolo_nano_v2/cam/image_raw/detections'
    )
    assert detections_channel('hsv', '/camera/image_raw/compressed') == (
        '/replaybench/hsv/camera/image_raw/compressed/detections'
    )


def test_written_file_decodes_with_mcap_ros2_to_the_same_values(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    _write_run(path)
    with path.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        assert {c.message_encoding for c in summary.channels.values()} == {'cdr'}
        assert {c.compression for c in summary.chunk_indexes} == {'zstd'}
        got = [
            (channel.topic, message.log_time, message.publish_time, decoded)
            for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False)
        ]
    assert [(topic, log, pub) for topic, log, pub, _ in got] == [
        ('/camera/camera_info', T0 + 1, T0 + 1),
        ('/replaybench/hsv/camera/image_raw/detections', T0 + 2, T0 + 2),
        ('/replaybench/yolo_nano/camera/image_raw/detections', T0 + 3, T0 + 3),
        ('/replaybench/hsv/camera/image_raw/detections', T0 + 40, T0 + 40),
        ('/replaybench/yolo_nano/camera/image_raw/detections', T0 + 41, T0 + 41),
    ]
    info = got[0][3]
    assert info.header.frame_id == 'camera_optical_frame'
    assert info.header.stamp.sec * 10**9 + info.header.stamp.nanosec == INFO.stamp_ns
    assert tuple(info.k) == INFO.k
    assert (info.width, info.height, info.distortion_model) == (320, 240, 'plumb_bob')
    for _, _, _, message in got[1:3]:
        assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == T0 - 5
        assert message.header.frame_id == 'camera_optical_frame'
    assert _boxes(got[1][3]) == _expected(RED, BLUE)
    assert _boxes(got[2][3]) == _expected(BLUE)
    assert got[3][3].detections == []
    assert got[4][3].header.stamp.nanosec == (T0 + 30) % 10**9


def test_written_file_reads_back_with_rosbags_anyreader(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    _write_run(path)
    # No typestore given: rosbags builds the types from the schemas in the file.
    with AnyReader([path]) as reader:
        topics = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
        assert topics == {
            '/camera/camera_info': ('sensor_msgs/msg/CameraInfo', 1),
            '/replaybench/hsv/camera/image_raw/detections': ('vision_msgs/msg/Detection2DArray', 2),
            '/replaybench/yolo_nano/camera/image_raw/detections': (
                'vision_msgs/msg/Detection2DArray',
                2,
            ),
        }
        decoded: list[tuple[str, int, Any]] = [
            (c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()
        ]
    hsv = [m for topic, _, m in decoded if topic.startswith('/replaybench/hsv/')]
    assert _boxes(hsv[0]) == _expected(RED, BLUE)
    assert len(hsv[1].detections) == 0
    assert hsv[1].header.frame_id == 'camera_optical_frame'
    assert [t for _, t, _ in decoded] == [T0 + 1, T0 + 2, T0 + 3, T0 + 40, T0 + 41]


def test_channels_and_schemas_are_registered_in_first_use_order(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    _write_run(path)
    with path.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    channels = [summary.channels[i].topic for i in sorted(summary.channels)]
    assert channels == [
        '/camera/camera_info',
        '/replaybench/hsv/camera/image_raw/detections',
        '/replaybench/yolo_nano/camera/image_raw/detections',
    ]
    schemas = [summary.schemas[i].name for i in sorted(summary.schemas)]
    assert schemas == ['sensor_msgs/msg/CameraInfo', 'vision_msgs/msg/Detection2DArray']


def test_messages_are_staged_until_finish_and_the_stage_is_gone_after(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    writer = DetectionsWriter(path)
    writer.add('hsv', '/camera/image_raw', T0, T0, 'cam', [RED])
    assert (tmp_path / 'detections.mcap.stage').exists()
    assert not path.exists()
    writer.finish()
    writer.finish()
    assert path.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ['detections.mcap']
    with pytest.raises(ValueError, match='already finished'):
        writer.add('hsv', '/camera/image_raw', T0, T0, 'cam', [RED])


def test_file_is_valid_after_an_exception_inside_the_with_block(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    with pytest.raises(RuntimeError, match='backend crashed'), DetectionsWriter(path) as writer:  # noqa: PT012  the exception passes through the context manager under test
        for i in range(3):
            writer.add('hsv', '/camera/image_raw', T0 + i, T0 + i, 'cam', [RED])
        msg = 'backend crashed'
        raise RuntimeError(msg)
    assert not (tmp_path / 'detections.mcap.part').exists()
    with path.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        assert summary.statistics is not None
        assert summary.statistics.message_count == 3
        stamps = [m.header.stamp.nanosec for *_, m in reader.iter_decoded_messages()]
    assert stamps == [0, 1, 2]
    with AnyReader([path]) as bag:
        assert sum(1 for _ in bag.messages()) == 3
