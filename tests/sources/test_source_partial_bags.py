"""Recordings replaybench can read only in part (issue 13, items 3, 13 and 14).

- rosbag2 folders whose recorder was killed before it wrote metadata.yaml: the storage files
  themselves are readable, so a folder holding one ``.db3`` / ``.mcap`` file, or the numbered
  files of one split bag, is replayed whole; any other folder is refused with one line that
  says how to go on. Passing the storage file itself replays every frame too.
- image topics in an encoding replaybench cannot read: listed with their count and the reason,
  skipped with a warning, refused when asked for by name.
- empty ROS 1 bags: empty, never truncated.
"""

from __future__ import annotations

import csv
import json
import sqlite3
from typing import TYPE_CHECKING

import pytest
from bagtools import TS
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from sourcebags import as_expected, expected_order, tie_plan, write_split_rosbag2
from typer.testing import CliRunner
from walbags import CAMERA, IMAGE, image_payloads

from replaybench.cli import app
from replaybench.errors import SourceError
from replaybench.sources import open_source
from replaybench.types import SkippedTopic

if TYPE_CHECKING:
    from pathlib import Path

TS1 = get_typestore(Stores.ROS1_NOETIC)


def write_camera_bag(path: Path, frames: int, storage: str) -> Path:
    """A rosbag2 folder of ``frames`` camera images; its metadata.yaml is removed (killed)."""
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conn = writer.add_connection(CAMERA, IMAGE, typestore=TS)
        for t, data in image_payloads(frames):
            writer.write(conn, t, data)
    (path / 'metadata.yaml').unlink()
    return path


def invoke(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, list(args))
    assert 'Traceback' not in result.output
    if result.exception is not None:
        assert isinstance(result.exception, SystemExit), result.exception
    return result.exit_code, result.stderr


def replayed_times(out: Path) -> list[int]:
    with (out / 'frames.csv').open(newline='') as handle:
        return [int(r['log_time_ns']) for r in csv.DictReader(handle) if r['topic'] == CAMERA]


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
@pytest.mark.parametrize('target', ['folder', 'storage-file'])
def test_a_bag_killed_before_metadata_yaml_replays_all_its_frames(tmp_path, storage, target):
    folder = write_camera_bag(tmp_path / 'bag', 45, storage)
    (data,) = [p for p in folder.iterdir() if p.suffix in ('.db3', '.mcap')]
    out = tmp_path / 'out'
    bag = folder if target == 'folder' else data
    code, stderr = invoke('run', str(bag), '--backend', 'null', '--no-report', '--out', str(out))
    assert code == 0, stderr
    assert replayed_times(out) == [t for t, _ in image_payloads(45)]
    if target == 'folder':
        warnings = json.loads((out / 'run.json').read_text())['inputs'][0]['warnings']
        assert any('metadata.yaml is missing' in w and data.name in w for w in warnings)


@pytest.mark.parametrize('storage', ['sqlite3', 'mcap'])
def test_the_files_of_a_split_bag_without_metadata_replay_as_one_bag_in_number_order(
    tmp_path, storage
):
    plan = tie_plan(24)
    parts = [plan[i : i + 6] for i in range(0, len(plan), 6)]  # 12 files: _10 sorts after _9
    parts += [[(topic, t + 10**12, text) for topic, t, text in plan[:3]]]
    folder = write_split_rosbag2(tmp_path / 'bag', parts, storage)
    (folder / 'metadata.yaml').unlink()
    assert len(list(folder.iterdir())) == len(parts) >= 11
    with open_source(folder) as source:
        got = as_expected(source.messages())
        warnings = source.warnings
    assert got == expected_order([m for part in parts for m in part])
    assert any('metadata.yaml is missing' in line for line in warnings)


def _refused(tmp_path: Path, folder: Path, *needles: str) -> None:
    with pytest.raises(SourceError) as info:
        open_source(folder)
    line = str(info.value)
    assert '\n' not in line
    for needle in needles:
        assert needle in line, line
    code, stderr = invoke('run', str(folder), '--backend', 'null', '--out', str(tmp_path / 'out'))
    assert code == 2
    assert stderr.count('\n') == 1
    assert stderr.startswith(f'replaybench: error: {folder}: ')


@pytest.mark.parametrize(
    'names',
    [['a_0.db3', 'b_0.mcap'], ['bag_0.db3', 'bag_2.db3'], ['front.db3', 'rear.db3']],
    ids=['db3-and-mcap', 'a-file-missing', 'two-bags'],
)
def test_storage_files_that_are_not_one_bag_without_metadata_are_refused_saying_how_to_go_on(
    tmp_path, names
):
    folder = tmp_path / 'bag'
    folder.mkdir()
    for name in names:
        source = write_camera_bag(tmp_path / f'src-{name}', 3, 'mcap' if 'mcap' in name else '')
        (data,) = list(source.iterdir())
        data.rename(folder / name)
    _refused(
        tmp_path,
        folder,
        'metadata.yaml is missing',
        'pass one storage file',
        'ros2 bag reindex',
        names[0],
    )


@pytest.mark.parametrize(
    ('names', 'hint'),
    [([], ''), (['notes.txt'], ''), (['old.bag'], 'pass the .bag file itself')],
    ids=['empty', 'no-bag-file', 'a-ros1-bag'],
)
def test_a_folder_without_any_bag_is_refused_in_one_line(tmp_path, names, hint):
    folder = tmp_path / 'empty'
    folder.mkdir()
    for name in names:
        (folder / name).write_bytes(b'#ROSBAG V2.0\n' if name.endswith('.bag') else b'hello\n')
    _refused(tmp_path, folder, 'no bag in this folder', hint)


# -- image topics in an encoding replaybench cannot read (item 13) --------------------------


def write_mcap_with_json_camera(path: Path, raw: int, json_frames: int, *, indexed: bool) -> Path:
    """An MCAP with ``raw`` CDR images on /cam/raw and ``json_frames`` JSON-encoded
    CompressedImage messages on /cam/json (``indexed=False``: no summary, no chunks)."""
    from mcap.writer import IndexType
    from mcap.writer import Writer as McapWriter

    extra: dict[str, object] = {}
    if not indexed:
        extra = {'index_types': IndexType.NONE, 'use_chunking': False, 'use_summary_offsets': False}
    with path.open('wb') as handle:
        writer = McapWriter(handle, **extra)  # type: ignore[arg-type]
        writer.start(profile='ros2', library='replaybench-tests')
        text = TS.generate_msgdef(IMAGE, ros_version=2)[0].encode()
        image_schema = writer.register_schema(IMAGE, 'ros2msg', text)
        json_schema = writer.register_schema('sensor_msgs/msg/CompressedImage', 'jsonschema', b'{}')
        cdr_channel = writer.register_channel('/cam/raw', 'cdr', image_schema) if raw else None
        json_channel = writer.register_channel('/cam/json', 'json', json_schema)
        for i, (t, data) in enumerate(image_payloads(max(raw, json_frames))):
            if cdr_channel is not None and i < raw:
                writer.add_message(cdr_channel, log_time=t, publish_time=t, data=data)
            if i < json_frames:
                doc = json.dumps({'format': 'jpeg', 'data': [255, 216, i]}).encode()
                writer.add_message(json_channel, log_time=t, publish_time=t, data=doc)
        writer.finish()
    return path


@pytest.mark.parametrize('indexed', [True, False], ids=['indexed', 'scanned'])
def test_an_image_topic_in_json_is_listed_by_info_with_its_count_and_why_it_is_skipped(
    tmp_path, indexed
):
    bag = write_mcap_with_json_camera(tmp_path / 'cams.mcap', 5, 7, indexed=indexed)
    with open_source(bag) as source:
        (skipped,) = source.skipped_topics()
    assert (skipped.name, skipped.encoding, skipped.count) == ('/cam/json', 'json', 7)
    result = CliRunner().invoke(app, ['info', str(bag)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert 'messages:   12' in lines
    (line,) = [x for x in lines if '/cam/json' in x]
    assert '7 msgs' in line
    assert "message encoding 'json' is not supported" in line


def test_run_warns_that_a_json_image_topic_is_skipped_and_replays_the_others(tmp_path):
    bag = write_mcap_with_json_camera(tmp_path / 'cams.mcap', 5, 7, indexed=True)
    out = tmp_path / 'out'
    code, stderr = invoke('run', str(bag), '--backend', 'null', '--no-report', '--out', str(out))
    assert code == 0, stderr
    assert any('/cam/json' in line and 'json' in line for line in stderr.splitlines())
    with (out / 'frames.csv').open(newline='') as handle:
        topics = [row['topic'] for row in csv.DictReader(handle)]
    assert topics == ['/cam/raw'] * 5


@pytest.mark.parametrize('raw', [5, 0], ids=['beside-a-readable-topic', 'alone'])
def test_run_topic_on_a_json_image_topic_exits_2_naming_the_encoding(tmp_path, raw):
    bag = write_mcap_with_json_camera(tmp_path / 'cams.mcap', raw, 7, indexed=True)
    out = str(tmp_path / 'out')
    code, stderr = invoke(
        'run', str(bag), '--topic', '/cam/json', '--backend', 'null', '--out', out
    )
    assert code == 2
    (error,) = [line for line in stderr.splitlines() if line.startswith('replaybench: error:')]
    assert '/cam/json' in error
    assert "'json'" in error


def test_run_on_a_bag_whose_only_image_topic_is_json_says_why_nothing_can_be_replayed(tmp_path):
    bag = write_mcap_with_json_camera(tmp_path / 'cams.mcap', 0, 7, indexed=False)
    code, stderr = invoke('run', str(bag), '--backend', 'null', '--out', str(tmp_path / 'out'))
    assert code == 2
    (error,) = [line for line in stderr.splitlines() if line.startswith('replaybench: error:')]
    assert 'no readable image topic' in error
    assert '/cam/json: 7 messages' in error
    assert "'json'" in error


def test_a_db3_topic_in_another_serialization_is_listed_with_its_count(tmp_path):
    folder = write_camera_bag(tmp_path / 'bag', 6, 'sqlite3')
    (db3,) = folder.glob('*.db3')
    with sqlite3.connect(db3) as db:
        db.execute("UPDATE topics SET serialization_format = 'json'")
    db.close()
    with open_source(db3) as source:
        assert source.skipped_topics() == [
            SkippedTopic(CAMERA, IMAGE, 'json', 6, "serialization 'json' is not supported")
        ]
        assert source.topics() == []
    result = CliRunner().invoke(app, ['info', str(db3)])
    assert result.exit_code == 0, result.output
    assert any(CAMERA in x and '6 msgs' in x and 'json' in x for x in result.stdout.splitlines())


def test_a_rosbag2_folder_with_a_json_image_topic_replays_its_cdr_topics(tmp_path):
    folder = tmp_path / 'bag'
    with Writer(folder, version=9) as writer:
        cdr = writer.add_connection(CAMERA, IMAGE, typestore=TS)
        other = writer.add_connection('/cam/json', IMAGE, typestore=TS, serialization_format='json')
        for t, data in image_payloads(6):
            writer.write(cdr, t, data)
            writer.write(other, t, b'{"height": 24}')
    code, stderr = invoke('info', str(folder))
    assert code == 0, stderr
    with open_source(folder) as source:
        assert [t.name for t in source.skipped_topics()] == ['/cam/json']
        assert [t.count for t in source.skipped_topics()] == [6]
    out = tmp_path / 'out'
    code, stderr = invoke('run', str(folder), '--backend', 'null', '--no-report', '--out', str(out))
    assert code == 0, stderr
    assert replayed_times(out) == [t for t, _ in image_payloads(6)]


# -- empty ROS 1 bags (item 14) ----------------------------------------------------------------


@pytest.mark.parametrize('connection', [True, False], ids=['a-connection', 'no-connection'])
def test_an_empty_ros1_bag_is_reported_as_empty_never_as_truncated(tmp_path, connection):
    from rosbags.rosbag1 import Writer as Writer1

    bag = tmp_path / 'empty.bag'
    writer = Writer1(bag)
    writer.open()
    if connection:
        writer.add_connection(CAMERA, IMAGE, typestore=TS1)
    writer.close()
    with open_source(bag) as source:
        assert not source.truncated
        assert source.warnings == []
        assert [t.count for t in source.topics()] == ([0] if connection else [])
    result = CliRunner().invoke(app, ['info', str(bag)])
    assert result.exit_code == 0
    assert 'format:     rosbag1' in result.stdout.splitlines()
    assert 'truncated' not in result.output
    code, stderr = invoke('run', str(bag), '--backend', 'null', '--out', str(tmp_path / 'out'))
    assert code == 2
    assert stderr == f'replaybench: error: {bag}: no messages in this file\n'
