"""Recorded latency: the `recorded` backend's outputs timed from the recording itself.

The bags are written with the real writers (mcap, rosbags' rosbag2 sqlite3) at known log times,
so every latency is known exactly.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from mcap.writer import Writer

from replaybench.fixtures.scene import Scene
from replaybench.msgs import (
    DETECTION2DARRAY,
    IMAGE,
    ros2msg_schema,
    serialize_detections,
    serialize_image,
    typestore,
)
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.results.recorded_latency import RECORDED_COLUMNS
from replaybench.results.tables import read_summary_csv

if TYPE_CHECKING:
    from collections.abc import Callable

REPO = Path(__file__).resolve().parents[2]
NS = 1_000_000_000
MS = 1_000_000
T0 = 1_700_000_000 * NS
PERIOD = NS // 30
IMAGE_TOPIC = '/camera/image_raw'
ROBOT_TOPIC = '/detectnet/detections'

# per frame: image log time after its stamp (transport to the recorder), output log time after
# the image's log time (the node's pipeline); None: the node published nothing for that frame
TRANSPORT_MS = [2, 3, 2, 4, 2, 3, 2, 2, 5, 2, 3, 2, 2, 4, 2, 3, 2, 2, 3, 2, 2, 4, 2, 3]
PIPELINE_MS = [41, 38, None, 45, 39, 40, 52, 37, None, 41, 43, 38, 40, 39, 44, 41, 38, 47, 40,
               39, 42, 41, None, 40]  # fmt: skip
FRAMES = len(PIPELINE_MS)

Messages = list[tuple[str, str, int, bytes]]  # (topic, msgtype, log time, data)


def _messages(
    stamp_of: Callable[[int], int] = lambda i: T0 + i * PERIOD,
    output_after_ms: Callable[[int], int | None] = lambda i: PIPELINE_MS[i],
    *,
    ros1: bool = False,
) -> Messages:
    """Images and the node's outputs (the truth with one box left out), by log time."""
    scene = Scene((96, 72), 0, 3)
    out: Messages = []
    for i in range(FRAMES):
        stamp = stamp_of(i)
        image_log = T0 + i * PERIOD + TRANSPORT_MS[i] * MS
        bgr, boxes = scene.render(i)
        image = serialize_image(stamp, 'cam', bgr, 'bgr8', ros1=ros1)
        out.append((IMAGE_TOPIC, IMAGE, image_log, image))
        after = output_after_ms(i)
        if after is not None:
            robot = [b._replace(score=0.9, id='') for b in boxes[1:]]  # a detector: no ids
            data = serialize_detections(stamp, 'cam', robot, ros1=ros1)
            out.append((ROBOT_TOPIC, DETECTION2DARRAY, image_log + after * MS, data))
    return sorted(out, key=lambda m: m[2])


def _write_mcap(path: Path, messages: Messages) -> Path:
    with path.open('wb') as f:
        writer = Writer(f)
        writer.start(profile='ros2', library='tests')
        channels: dict[str, int] = {}
        for topic, msgtype, log_time, data in messages:
            if topic not in channels:
                schema = writer.register_schema(
                    msgtype, 'ros2msg', ros2msg_schema(msgtype).encode()
                )
                channels[topic] = writer.register_channel(topic, 'cdr', schema)
            writer.add_message(channels[topic], log_time, data, log_time)
        writer.finish()
    return path


def _write_rosbag2(path: Path, messages: Messages) -> Path:
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Rosbag2Writer

    store = typestore()
    with Rosbag2Writer(path, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        connections = {}
        for topic, msgtype, log_time, data in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], log_time, data)
    return path


def _write_rosbag1(path: Path, messages: Messages) -> Path:
    from rosbags.rosbag1 import Writer as Rosbag1Writer

    store = typestore(ros1=True)
    with Rosbag1Writer(path) as writer:
        connections = {}
        for topic, msgtype, log_time, data in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], log_time, data)
    return path


def _run(bag: Path, out: Path, backends: tuple[str, ...] = ('recorded', 'null')):
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=list(backends), out_dir=out, report=False)
    )
    with (out / 'frames.csv').open(newline='') as f:
        rows = [r for r in csv.DictReader(f) if r['backend'] == 'recorded']
    summary = {s.backend: s for s in outcome.run.summary_rows}
    return rows, summary, outcome


@pytest.mark.parametrize(
    'writer', [_write_mcap, _write_rosbag2, _write_rosbag1], ids=['mcap', 'rosbag2', 'ros1']
)
def test_known_log_times_give_exact_recorded_latencies(tmp_path, writer):
    ros1 = writer is _write_rosbag1
    bag = writer(tmp_path / ('robot.bag' if ros1 else 'robot'), _messages(ros1=ros1))
    rows, summary, _ = _run(bag, tmp_path / 'run')

    assert len(rows) == FRAMES
    pipeline, capture = [], []
    for i, row in enumerate(rows):
        after = PIPELINE_MS[i]
        if after is None:
            assert row['output_log_time_ns'] == ''
            assert row['pipeline_ms'] == row['capture_to_output_ms'] == ''
            assert row['note'].endswith('no recorded output for this frame')
            continue
        image_log = T0 + i * PERIOD + TRANSPORT_MS[i] * MS
        assert int(row['output_log_time_ns']) == image_log + after * MS
        assert float(row['pipeline_ms']) == after
        assert float(row['capture_to_output_ms']) == after + TRANSPORT_MS[i]
        assert row['latency_ms'] == ''  # the replay's own latency stays not measured
        pipeline.append(after)
        capture.append(after + TRANSPORT_MS[i])

    rec = summary['recorded']
    assert rec.latency_ms_p50 is None
    assert rec.recorded_outputs == FRAMES - 3
    assert rec.recorded_outputs_dropped == 3
    assert rec.pipeline_ms_p50 == pytest.approx(float(np.percentile(pipeline, 50)))
    assert rec.pipeline_ms_p99 == pytest.approx(float(np.percentile(pipeline, 99)))
    assert rec.pipeline_ms_mean == pytest.approx(float(np.mean(pipeline)))
    assert rec.pipeline_ms_max == 52
    assert rec.capture_to_output_ms_p50 == pytest.approx(float(np.percentile(capture, 50)))
    assert rec.capture_to_output_ms_max == pytest.approx(max(capture))
    logged = [T0 + i * PERIOD + (TRANSPORT_MS[i] + a) * MS for i, a in enumerate(PIPELINE_MS) if a]
    assert rec.recorded_output_hz == pytest.approx(
        (len(logged) - 1) * NS / (logged[-1] - logged[0])
    )
    assert rec.recorded_latency_note == ''  # 21 outputs: intervals, nothing refused
    assert rec.pipeline_ms_p50_ci_low is not None
    assert rec.pipeline_ms_p50_ci_high is not None
    assert rec.pipeline_ms_p50_ci_low <= rec.pipeline_ms_p50 <= rec.pipeline_ms_p50_ci_high
    assert rec.capture_to_output_ms_p99_ci_high is not None
    # a replayed backend has none of it
    assert summary['null'].recorded_outputs is None
    assert summary['null'].pipeline_ms_p50 is None
    assert summary['null'].latency_ms_p50 is not None


def test_repeated_passes_count_each_recorded_output_once(tmp_path):
    bag = _write_mcap(tmp_path / 'robot.mcap', _messages())
    _, once, _ = _run(bag, tmp_path / 'once')
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['recorded', 'null'], out_dir=None, repeat=3)
    )
    thrice = {s.backend: s for s in outcome.run.summary_rows}
    for column in RECORDED_COLUMNS:
        assert getattr(thrice['recorded'], column) == getattr(once['recorded'], column), column
    assert once['recorded'].recorded_outputs == sum(ms is not None for ms in PIPELINE_MS)


def test_recorded_latency_is_in_summary_csv_and_a_valid_run_json(tmp_path):
    import jsonschema

    bag = _write_mcap(tmp_path / 'robot.mcap', _messages())
    out = tmp_path / 'run'
    _, summary, _ = _run(bag, out)
    pytest.importorskip('pandas')
    table = read_summary_csv(out / 'summary.csv').set_index('backend')
    for column in RECORDED_COLUMNS:
        if column == 'recorded_latency_note':
            continue
        written = table.loc['recorded', column]
        assert written == pytest.approx(getattr(summary['recorded'], column), abs=1e-4)
    document = json.loads((out / 'run.json').read_text())
    schema = json.loads((REPO / 'replaybench' / 'schemas' / 'run.schema.json').read_text())
    jsonschema.Draft202012Validator(schema).validate(document)
    row = next(r for r in document['summary'] if r['backend'] == 'recorded')
    assert row['pipeline_ms_p50'] == summary['recorded'].pipeline_ms_p50


def test_outputs_logged_before_their_images_give_the_note_and_no_number(tmp_path):
    """A recorder whose clock disagrees: every output logged 5 ms before its image."""
    bag = _write_mcap(tmp_path / 'inverted.mcap', _messages(output_after_ms=lambda i: -5))
    rows, summary, _ = _run(bag, tmp_path / 'run')
    assert all(r['output_log_time_ns'] != '' for r in rows)
    assert all(r['pipeline_ms'] == r['capture_to_output_ms'] == '' for r in rows)
    assert all('logged before its image' in r['note'] for r in rows)
    rec = summary['recorded']
    assert rec.recorded_outputs == FRAMES
    for figure in ('pipeline_ms', 'capture_to_output_ms'):
        for stat in ('mean', 'p50', 'p50_ci_low', 'p99', 'max'):
            assert getattr(rec, f'{figure}_{stat}') is None
    note = rec.recorded_latency_note or ''
    assert (
        f'pipeline latency not reported: {FRAMES} of {FRAMES} recorded outputs were logged '
        'before their image' in note
    )
    assert 'capture-to-output latency not reported' in note


def test_one_output_before_its_image_refuses_the_whole_figure(tmp_path):
    bag = _write_mcap(
        tmp_path / 'one.mcap',
        _messages(output_after_ms=lambda i: -1 if i == 5 else 40),
    )
    rows, summary, _ = _run(bag, tmp_path / 'run')
    assert rows[4]['pipeline_ms'] == '40.0000'
    assert rows[5]['pipeline_ms'] == ''
    rec = summary['recorded']
    assert rec.pipeline_ms_p50 is None
    assert f'1 of {FRAMES} recorded outputs were logged before their image' in (
        rec.recorded_latency_note or ''
    )


def test_zero_stamps_give_the_note_and_no_number(tmp_path):
    bag = _write_mcap(tmp_path / 'zero.mcap', _messages(stamp_of=lambda i: 0))
    rows, summary, _ = _run(bag, tmp_path / 'run')
    assert all(r['pipeline_ms'] == r['capture_to_output_ms'] == '' for r in rows)
    assert all('zero header stamp' in r['note'] for r in rows)
    rec = summary['recorded']
    assert rec.pipeline_ms_p50 is None
    assert rec.capture_to_output_ms_p50 is None
    assert 'zero header stamp' in (rec.recorded_latency_note or '')


def test_a_camera_clock_ahead_of_the_recorder_refuses_capture_to_output_only(tmp_path):
    """Images stamped 50 ms after the recorder logged them: the pipeline figure still holds."""
    bag = _write_mcap(
        tmp_path / 'ahead.mcap', _messages(stamp_of=lambda i: T0 + i * PERIOD + 50 * MS)
    )
    rows, summary, _ = _run(bag, tmp_path / 'run')
    matched = [r for r in rows if r['output_log_time_ns']]
    assert all(r['capture_to_output_ms'] == '' and r['pipeline_ms'] != '' for r in matched)
    rec = summary['recorded']
    assert rec.capture_to_output_ms_p50 is None
    assert rec.pipeline_ms_p50 == pytest.approx(
        float(np.percentile([a for a in PIPELINE_MS if a is not None], 50))
    )
    assert 'stamped after it was logged' in (rec.recorded_latency_note or '')


def test_simulated_time_stamps_refuse_capture_to_output(tmp_path):
    """Stamps in simulated time (seconds since start) against a wall-clock recorder."""
    bag = _write_mcap(tmp_path / 'sim.mcap', _messages(stamp_of=lambda i: NS + i * PERIOD))
    _, summary, _ = _run(bag, tmp_path / 'run', backends=('recorded',))
    rec = summary['recorded']
    assert rec.capture_to_output_ms_p50 is None
    assert rec.pipeline_ms_p50 is not None
    assert 'more than 10 s before it was logged' in (rec.recorded_latency_note or '')


def test_few_outputs_are_summarised_without_an_interval(tmp_path):
    messages = [m for m in _messages() if m[2] < T0 + 8 * PERIOD]
    bag = _write_mcap(tmp_path / 'short.mcap', messages)
    _, summary, _ = _run(bag, tmp_path / 'run', backends=('recorded',))
    rec = summary['recorded']
    assert rec.pipeline_ms_p50 is not None
    assert rec.pipeline_ms_p50_ci_low is None
    assert 'fewer than 20, no 95 % interval' in (rec.recorded_latency_note or '')


def test_a_row_without_replay_latency_has_no_too_few_measured_frames_warning(tmp_path):
    # 8 frames: the replayed `null` row is warned of its few measured frames; the `recorded`
    # row has no replay latency to measure, and its outputs' few frames are in its note
    messages = [m for m in _messages() if m[2] < T0 + 8 * PERIOD]
    bag = _write_mcap(tmp_path / 'short.mcap', messages)
    _, summary, _ = _run(bag, tmp_path / 'run')
    assert not any('measured frames' in w for w in summary['recorded'].warnings)
    assert any('measured frames: fewer than 20' in w for w in summary['null'].warnings)
    assert 'fewer than 20, no 95 % interval' in (summary['recorded'].recorded_latency_note or '')


def test_a_recorded_topic_of_a_type_without_a_reader_is_refused(tmp_path):
    from replaybench.errors import UsageError
    from replaybench.fixtures.writer import camera_info
    from replaybench.msgs import CAMERA_INFO, serialize_camera_info

    info = serialize_camera_info(camera_info((96, 72), T0, 'cam'))
    bag = _write_mcap(
        tmp_path / 'robot.mcap', [('/camera/camera_info', CAMERA_INFO, T0, info), *_messages()]
    )
    with pytest.raises(
        UsageError,
        match=r'is a sensor_msgs/msg/CameraInfo topic; the recorded backend reads '
        r'vision_msgs/msg/Detection2DArray \(detections\), '
        r'isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray \(tags\), '
        r'sensor_msgs/msg/Image \(masks, named with --recorded-topic\), '
        r'stereo_msgs/msg/DisparityImage \(disparity images\)$',
    ):
        run_benchmark(
            RunConfig(
                inputs=[bag],
                backends=['recorded'],
                out_dir=None,
                recorded_topic='/camera/camera_info',
                report=False,
            )
        )


def test_frames_and_summary_csv_written_before_the_recorded_columns_still_read(tmp_path):
    from replaybench.results.records import FRAMES_CSV_COLUMNS, read_frames_csv
    from replaybench.results.stats import SUMMARY_CSV_COLUMNS

    bag = _write_mcap(tmp_path / 'robot.mcap', _messages())
    out = tmp_path / 'run'
    _run(bag, out)
    old = tmp_path / 'old'
    old.mkdir()
    with (out / 'frames.csv').open(newline='') as f:
        frames = list(csv.reader(f))
    with (old / 'frames.csv').open('w', newline='') as f:
        csv.writer(f, lineterminator='\r\n').writerows(row[:27] for row in frames)
    with (out / 'summary.csv').open(newline='') as f:
        summary = list(csv.reader(f))
    with (old / 'summary.csv').open('w', newline='') as f:
        csv.writer(f, lineterminator='\r\n').writerows(
            row[: summary[0].index('warnings') + 1] for row in summary
        )

    assert frames[0][27:] == list(FRAMES_CSV_COLUMNS[27:])
    records = read_frames_csv(old / 'frames.csv')
    assert len(records) == len(frames) - 1
    assert all(r.output_log_time_ns is None and r.pipeline_ms is None for r in records)
    assert any(r.pipeline_ms is not None for r in read_frames_csv(out / 'frames.csv'))
    pytest.importorskip('pandas')
    table = read_summary_csv(old / 'summary.csv')
    assert tuple(table.columns) == SUMMARY_CSV_COLUMNS
    assert table['pipeline_ms_p50'].isna().all()


def test_one_reader_entry_is_all_another_recorded_output_type_needs(tmp_path, monkeypatch):
    """Another message type of a task's recorded output is one ``RECORDED_READERS`` entry:
    here CameraInfo read as an "output" of the detections task (one box the size of the image),
    matched, scored and timed like detections."""
    from replaybench.decode import decode_camera_info
    from replaybench.decode import recorded as recorded_outputs
    from replaybench.fixtures.writer import camera_info
    from replaybench.msgs import CAMERA_INFO, serialize_camera_info
    from replaybench.replay import recorded as recorded_table
    from replaybench.types import BackendResult, Detection

    def read_camera_info(raw):
        info = decode_camera_info(raw)
        box = Detection(0, 'frame', 1.0, 0.0, 0.0, float(info.width), float(info.height))
        return recorded_outputs.RecordedMessage(info.frame_id, info.stamp_ns, BackendResult((box,)))

    entry = recorded_outputs.OutputReader('detections', read_camera_info, candidate=False)
    monkeypatch.setitem(recorded_table.RECORDED_READERS, CAMERA_INFO, entry)
    messages = [m for m in _messages() if m[0] == IMAGE_TOPIC]
    for _, _, image_log, _ in list(messages):
        stamp = T0 + (image_log - T0) // PERIOD * PERIOD
        data = serialize_camera_info(camera_info((96, 72), stamp, 'cam'))
        messages.append(('/camera/camera_info', CAMERA_INFO, image_log + 7 * MS, data))
    bag = _write_mcap(tmp_path / 'info.mcap', sorted(messages, key=lambda m: m[2]))
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['recorded'],
            out_dir=None,
            recorded_topic='/camera/camera_info',
            report=False,
        )
    )
    rows = [r for r in outcome.records if r.backend == 'recorded']
    assert len(rows) == FRAMES
    assert all(r.detections == 1 for r in rows)
    assert all(r.pipeline_ms == 7 for r in rows)
    [row] = outcome.run.summary_rows
    assert row.recorded_outputs == FRAMES
    assert row.pipeline_ms_p50 == 7
    assert row.recorded_outputs_dropped == 0


def test_without_a_recorded_topic_to_pick_alone_the_error_names_what_it_reads(tmp_path):
    from replaybench.errors import UsageError

    bag = _write_mcap(tmp_path / 'none.mcap', [m for m in _messages() if m[0] == IMAGE_TOPIC])
    with pytest.raises(
        UsageError,
        match=r'needs --recorded-topic TOPIC \(topics it can pick alone '
        r'besides the ground truth: none; it reads vision_msgs/msg/Detection2DArray '
        r'\(detections\), isaac_ros_apriltag_interfaces/msg/AprilTagDetectionArray \(tags\), '
        r'sensor_msgs/msg/Image \(masks, named with --recorded-topic\), '
        r'stereo_msgs/msg/DisparityImage \(disparity images\)\)$',
    ):
        run_benchmark(RunConfig(inputs=[bag], backends=['recorded'], out_dir=None, report=False))
