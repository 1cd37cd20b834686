"""--annotations against the current foxglove_msgs: the .msg files Foxglove publishes today.

``foxglove_msgs_ros2/`` holds the foxglove_msgs 3.4 ROS 2 definitions verbatim (comments and
all); Foxglove's own protobuf schemas package (foxglove-schemas-protobuf) gives the same field
lists independently.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest
from foxglove_schemas_protobuf import (
    CircleAnnotation_pb2,
    ImageAnnotations_pb2,
    KeyValuePair_pb2,
    PointsAnnotation_pb2,
    TextAnnotation_pb2,
)
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from replaybench import msgs
from replaybench.sinks import DetectionsWriter, serialize_image_annotations
from replaybench.types import Detection

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

UPSTREAM = Path(__file__).resolve().parent / 'foxglove_msgs_ros2'
DOC = Path(__file__).resolve().parents[2] / 'docs' / 'foxglove.md'
T0 = 1_700_000_000_123_456_789
RED = Detection(0, 'red', 0.875, 10.0, 20.0, 30.0, 60.0)
BLUE = Detection(2, 'blue', 0.25, 100.5, 0.0, 120.0, 8.0)
CAM = '/camera/image_raw'
ANNOTATIONS = '/replaybench/hsv/camera/image_raw/annotations'
NAMES = [
    'ImageAnnotations',
    'CircleAnnotation',
    'PointsAnnotation',
    'TextAnnotation',
    'KeyValuePair',
    'Point2',
    'Color',
]


def _upstream_store() -> Typestore:
    """A Humble typestore with the published foxglove_msgs .msg files registered."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name in NAMES:
        text = (UPSTREAM / f'{name}.msg').read_text()
        types.update(get_types_from_msg(text, f'foxglove_msgs/msg/{name}'))
    store.register(types)
    return store


def _fields(text: str) -> list[str]:
    """The declarations of a .msg text: comments and blank lines left out."""
    lines = (line.split('#', 1)[0].strip() for line in text.splitlines())
    return [line for line in lines if line]


def _write(path: Path) -> None:
    with DetectionsWriter(path, annotations=True, backends=['hsv']) as writer:
        writer.add('hsv', CAM, T0 + 7, T0, 'cam', [RED, BLUE])
        writer.add('hsv', CAM, T0 + 40, T0 + 33, 'cam', [])


def _stamp(time: Any) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


@pytest.mark.parametrize('name', NAMES)
def test_each_definition_declares_the_published_fields_in_order(name: str) -> None:
    published = _fields((UPSTREAM / f'{name}.msg').read_text())
    ours = _fields(msgs.FOXGLOVE_MSGS_ROS2[f'foxglove_msgs/msg/{name}'])
    assert ours == published


@pytest.mark.parametrize(
    ('name', 'module'),
    [
        ('ImageAnnotations', ImageAnnotations_pb2),
        ('CircleAnnotation', CircleAnnotation_pb2),
        ('PointsAnnotation', PointsAnnotation_pb2),
        ('TextAnnotation', TextAnnotation_pb2),
        ('KeyValuePair', KeyValuePair_pb2),
    ],
)
def test_field_names_match_foxgloves_published_protobuf_schemas(name: str, module: Any) -> None:
    protobuf = [field.name for field in getattr(module, name).DESCRIPTOR.fields]
    ours = [
        line.split()[1]
        for line in _fields(msgs.FOXGLOVE_MSGS_ROS2[f'foxglove_msgs/msg/{name}'])
        if '=' not in line
    ]
    assert ours == protobuf


def test_the_current_definitions_decode_every_annotation_field(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    _write(path)
    store = _upstream_store()
    with path.open('rb') as stream:
        reader = make_reader(stream)
        data = [m.data for _, _, m in reader.iter_messages(topics=[ANNOTATIONS])]
    assert len(data) == 2
    first: Any = store.deserialize_cdr(data[0], msgs.IMAGE_ANNOTATIONS)
    assert _stamp(first.timestamp) == T0
    assert first.metadata == []
    assert first.circles == []
    assert [p.type for p in first.points] == [2, 2]
    for det, box, text in zip([RED, BLUE], first.points, first.texts, strict=True):
        assert [(p.x, p.y) for p in box.points] == [
            (det.x0, det.y0),
            (det.x1, det.y0),
            (det.x1, det.y1),
            (det.x0, det.y1),
        ]
        assert _stamp(box.timestamp) == _stamp(text.timestamp) == T0
        assert box.metadata == text.metadata == []
        assert text.text == f'{det.label} {det.score:.2f}'
    empty: Any = store.deserialize_cdr(data[1], msgs.IMAGE_ANNOTATIONS)
    assert _stamp(empty.timestamp) == T0 + 33
    assert (empty.circles, empty.points, empty.texts, empty.metadata) == ([], [], [], [])


def test_the_bytes_are_what_the_current_definitions_serialise() -> None:
    store = _upstream_store()
    ours = serialize_image_annotations(T0, [RED, BLUE], '#0072b2')
    decoded = store.deserialize_cdr(ours, msgs.IMAGE_ANNOTATIONS)
    assert bytes(store.serialize_cdr(decoded, msgs.IMAGE_ANNOTATIONS)) == ours


def test_the_embedded_schema_and_type_hash_are_those_of_the_current_definitions(
    tmp_path: Path,
) -> None:
    path = tmp_path / 'detections.mcap'
    _write(path)
    store = _upstream_store()
    with path.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    (channel,) = [c for c in summary.channels.values() if c.topic == ANNOTATIONS]
    schema = summary.schemas[channel.schema_id]
    assert (schema.name, schema.encoding) == (msgs.IMAGE_ANNOTATIONS, 'ros2msg')
    blocks = re.split(r'\n=+\nMSG: ', schema.data.decode())
    embedded = {msgs.IMAGE_ANNOTATIONS: blocks[0]}
    for block in blocks[1:]:
        name, text = block.split('\n', 1)
        embedded[name.replace('/', '/msg/', 1)] = text
    for name in NAMES:
        published = _fields((UPSTREAM / f'{name}.msg').read_text())
        written = _fields(embedded[f'foxglove_msgs/msg/{name}'])
        # the fields in order; the constants (rosbags writes them first) as a set
        assert [f for f in written if '=' not in f] == [f for f in published if '=' not in f]
        assert {f for f in written if '=' in f} == {f for f in published if '=' in f}
    assert channel.metadata['topic_type_hash'] == store.hash_rihs01(msgs.IMAGE_ANNOTATIONS)


def test_mcap_ros2_and_rosbags_decode_with_the_embedded_schema_alone(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    _write(path)
    with path.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        by_mcap = [m for _, _, _, m in reader.iter_decoded_messages(topics=[ANNOTATIONS])]
    with AnyReader([path]) as bag:
        connections = [c for c in bag.connections if c.topic == ANNOTATIONS]
        by_rosbags: list[Any] = [
            bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages(connections)
        ]
    for decoded in (by_mcap, by_rosbags):
        assert [_stamp(m.timestamp) for m in decoded] == [T0, T0 + 33]
        assert [len(m.texts) for m in decoded] == [2, 0]
        assert decoded[0].texts[1].text == 'blue 0.25'


def test_the_version_in_code_is_the_one_the_docs_name() -> None:
    assert msgs.FOXGLOVE_MSGS_VERSION == '3.4.3'
    assert f'foxglove_msgs {msgs.FOXGLOVE_MSGS_VERSION}' in DOC.read_text()
