"""Hostile text in a bag: control sequences in topic names, frame ids, schema names, labels.

The bag is written with the real mcap writer and rosbags serialisation. Whatever replaybench
shows - ``info`` and ``run`` on a pipe and on a terminal, ``compare``, report.html,
comparison.html, frames.csv, summary.csv, comparison.csv - holds the control characters as
visible escapes (``\\x1b``), CSV cells of bag text that a spreadsheet would run as a formula
start with an apostrophe, and run.json and outputs.mcap keep the true names.
"""

from __future__ import annotations

import csv
import io
import json
import os
import pty
import re
import select
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.writer import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from replaybench.decode import decode_detections
from replaybench.fixtures.scene import Scene
from replaybench.msgs import VISION_MSGS_ROS2
from replaybench.results.records import FrameRecord, FramesCsvWriter, read_frames_csv
from replaybench.sinks.mcap_writer import detections_channel
from replaybench.sources import open_source
from replaybench.textsafe import csv_text, escape, from_csv, unescape, visible, visible_lines

if TYPE_CHECKING:
    from replaybench.types import Detection

REPO = Path(__file__).resolve().parents[1]

#: Sets the window title, rings the bell, clears the screen.
TOPIC = '/cam\x1b]0;pwned\x07\x1b[2J'
#: A topic a spreadsheet would run as a formula (MCAP does not enforce ROS names).
FORMULA_TOPIC = '=HYPERLINK("http://evil.example","x")'
FRAME_ID = 'cam\x1b[31m\x9b1m'
#: The encoding of one more image on TOPIC: it cannot be decoded, and the reason names it.
ENCODING = 'bgr8\x1b[2J\x1b]0;enc\x07'
DETECTIONS_TOPIC = '/robot\x1b[1m/detections'
OTHER_TOPIC = '/chatter\x1b[5m\r'
OTHER_SCHEMA = 'std_msgs/msg/String\x1b]2;title\x07'
#: Scene classes -> hostile labels (ESC sequences, a formula, a C1 CSI, a bidi override).
LABELS = {
    'red': '\x1b]0;red\x07red',
    'green': '=1+2',
    'blue': '-2',
    'yellow': '@SUM(A1)\u202eyellow\x9b2J',
}
#: Raw characters that must not reach a terminal, report or CSV (LF only as a line end).
RAW = re.compile('[\x00-\x09\x0b-\x1f\x7f-\x9f\u202a-\u202e\u2066-\u2069]')

_TS = get_typestore(Stores.ROS2_HUMBLE)
_TS.register(
    {k: v for n, t in VISION_MSGS_ROS2.items() for k, v in get_types_from_msg(t, n).items()}
)
T = _TS.types


def _header(stamp: int, frame_id: str) -> Any:
    time = T['builtin_interfaces/msg/Time'](sec=stamp // 10**9, nanosec=stamp % 10**9)
    return T['std_msgs/msg/Header'](stamp=time, frame_id=frame_id)


def _image(stamp: int, frame_id: str, bgr: np.ndarray, encoding: str = 'bgr8') -> Any:
    height, width = bgr.shape[:2]
    return T['sensor_msgs/msg/Image'](
        header=_header(stamp, frame_id),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * 3,
        data=np.frombuffer(bgr.tobytes(), np.uint8),
    )


def _detections(stamp: int, frame_id: str, truth: list[Detection]) -> Any:
    pose = T['geometry_msgs/msg/PoseWithCovariance'](
        pose=T['geometry_msgs/msg/Pose'](
            position=T['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.0),
            orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
        covariance=np.zeros(36),
    )
    items = []
    for det in truth:
        centre = T['vision_msgs/msg/Pose2D'](
            position=T['vision_msgs/msg/Point2D'](x=(det.x0 + det.x1) / 2, y=(det.y0 + det.y1) / 2),
            theta=0.0,
        )
        hypothesis = T['vision_msgs/msg/ObjectHypothesisWithPose'](
            hypothesis=T['vision_msgs/msg/ObjectHypothesis'](class_id=LABELS[det.label], score=1.0),
            pose=pose,
        )
        items.append(
            T['vision_msgs/msg/Detection2D'](
                header=_header(stamp, frame_id),
                results=[hypothesis],
                bbox=T['vision_msgs/msg/BoundingBox2D'](
                    center=centre, size_x=float(det.x1 - det.x0), size_y=float(det.y1 - det.y0)
                ),
                id='',
            )
        )
    return T['vision_msgs/msg/Detection2DArray'](header=_header(stamp, frame_id), detections=items)


def write_hostile_bag(path: Path, frames: int = 6) -> Path:
    """Images on TOPIC and FORMULA_TOPIC, ground truth and recorded detections with hostile
    labels, and a topic whose schema name holds control sequences."""
    scene = Scene((96, 72), 0, 7)
    with path.open('wb') as handle:
        writer = Writer(handle)
        writer.start(profile='ros2', library='tests')
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}

        def add(topic: str, msgtype: str, message: object, log_ns: int) -> None:
            if msgtype not in schemas:
                text = _TS.generate_msgdef(msgtype, ros_version=2)[0]
                schemas[msgtype] = writer.register_schema(msgtype, 'ros2msg', text.encode())
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, 'cdr', schemas[msgtype])
            data = bytes(_TS.serialize_cdr(message, msgtype))
            writer.add_message(channels[topic], log_time=log_ns, publish_time=log_ns, data=data)

        other_schema = writer.register_schema(OTHER_SCHEMA, 'ros2msg', b'string data\n')
        other = writer.register_channel(OTHER_TOPIC, 'cdr', other_schema)
        for i in range(frames):
            stamp = 1_700_000_000 * 10**9 + i * 10**8
            bgr, truth = scene.render(i)
            add(TOPIC, 'sensor_msgs/msg/Image', _image(stamp, FRAME_ID, bgr), stamp)
            add(FORMULA_TOPIC, 'sensor_msgs/msg/Image', _image(stamp, 'plain', bgr), stamp)
            dets = _detections(stamp, FRAME_ID, truth)
            add('/ground_truth/detections', 'vision_msgs/msg/Detection2DArray', dets, stamp)
            add(DETECTIONS_TOPIC, 'vision_msgs/msg/Detection2DArray', dets, stamp)
            payload = b'\x00\x01\x00\x00\x04\x00\x00\x00hi!\x00'
            writer.add_message(other, log_time=stamp, publish_time=stamp, data=payload)
        stamp = 1_700_000_000 * 10**9 + frames * 10**8
        add(TOPIC, 'sensor_msgs/msg/Image', _image(stamp, FRAME_ID, bgr, ENCODING), stamp)
        writer.finish()
    return path


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        capture_output=True,
        text=True,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore', 'COLUMNS': '200'},
        timeout=300,
        check=False,
        cwd=REPO,
    )


def _on_a_terminal(*args: str) -> tuple[int, str]:
    """Run the CLI with stdout and stderr on a pseudo-terminal; its exit code and output."""
    controller, terminal = pty.openpty()
    process = subprocess.Popen(
        [sys.executable, '-m', 'replaybench', *args],
        stdout=terminal,
        stderr=terminal,
        stdin=subprocess.DEVNULL,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
        cwd=REPO,
    )
    os.close(terminal)
    chunks = []
    while True:
        ready, _, _ = select.select([controller], [], [], 120)
        if not ready:
            process.kill()
            break
        try:
            chunk = os.read(controller, 65536)
        except OSError:  # the terminal closed: the process is gone
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(controller)
    code = process.wait(timeout=60)
    return code, b''.join(chunks).decode('utf-8', 'replace').replace('\r\n', '\n')


def _assert_no_raw_controls(text: str, where: str) -> None:
    found = RAW.search(text)
    assert found is None, f'{where}: raw {found.group()!r} at {found.start()}'


@pytest.fixture(scope='module')
def hostile_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_hostile_bag(tmp_path_factory.mktemp('hostile') / 'hostile.mcap')


@pytest.fixture(scope='module')
def hostile_runs(tmp_path_factory: pytest.TempPathFactory, hostile_bag: Path):
    """Two runs of the hostile bag (null and recorded) and their terminal output."""
    root = tmp_path_factory.mktemp('runs')
    results = []
    for name in ('a', 'b'):
        result = _cli(
            'run', str(hostile_bag), '--backend', 'null', '--backend', 'recorded',
            '--out', str(root / name),
        )  # fmt: skip
        assert result.returncode == 0, result.stderr
        results.append(result)
    return root, results


# --- info ------------------------------------------------------------------------------------


def test_info_shows_control_sequences_of_names_as_escapes_in_a_pipe(hostile_bag):
    result = _cli('info', str(hostile_bag))
    assert result.returncode == 0, result.stderr
    _assert_no_raw_controls(result.stdout, 'stdout')
    _assert_no_raw_controls(result.stderr, 'stderr')
    assert visible(TOPIC) in result.stdout
    assert r'/cam\x1b]0;pwned\x07\x1b[2J' in result.stdout
    assert visible(OTHER_TOPIC) in result.stdout
    assert r'std_msgs/msg/String\x1b]2;title\x07' in result.stdout
    assert visible(DETECTIONS_TOPIC) in result.stdout


def test_info_on_a_terminal_neither_sets_the_title_nor_clears_the_screen(hostile_bag):
    code, output = _on_a_terminal('info', str(hostile_bag))
    assert code == 0, output
    _assert_no_raw_controls(output, 'terminal')
    assert r'/cam\x1b]0;pwned\x07\x1b[2J' in output


# --- run -------------------------------------------------------------------------------------


def test_run_prints_its_table_and_warnings_with_names_escaped(hostile_runs):
    _, results = hostile_runs
    for result in results:
        _assert_no_raw_controls(result.stdout, 'stdout')
        _assert_no_raw_controls(result.stderr, 'stderr')
        table = result.stdout.splitlines()
        assert any(line.startswith('null') and visible(TOPIC) in line for line in table)
        assert any(line.startswith('recorded') and FORMULA_TOPIC in line for line in table)
        # besides the run's statistics warnings (few frames: no interval), named per backend
        (warning,) = [w for w in result.stderr.splitlines() if 'skipped' in w]
        assert warning.startswith('replaybench: warning: skipped 2 message(s): ')
        assert r'bgr8\x1b[2J\x1b]0;enc\x07' in warning


def test_run_on_a_terminal_shows_the_summary_table_escaped(hostile_bag, tmp_path):
    code, output = _on_a_terminal(
        'run', str(hostile_bag), '--backend', 'null', '--out', str(tmp_path / 'run'), '--no-report'
    )
    assert code == 0, output
    # the progress bar's own carriage returns redraw its line
    _assert_no_raw_controls(output.replace('\r[', '['), 'terminal')
    assert visible(TOPIC) in output


def test_frames_csv_holds_escaped_names_and_reads_back_the_true_ones(hostile_runs):
    root, _ = hostile_runs
    path = root / 'a' / 'frames.csv'
    text = path.read_bytes().decode('utf-8')
    _assert_no_raw_controls(text.replace('\r\n', ''), 'frames.csv')
    with path.open(newline='', encoding='utf-8') as handle:
        topics = {row['topic'] for row in csv.DictReader(handle)}
    assert topics == {escape(TOPIC), "'" + FORMULA_TOPIC}
    records = read_frames_csv(path)
    assert {r.topic for r in records} == {TOPIC, FORMULA_TOPIC}
    assert {r.note for r in records if r.status == 'skipped'} == {
        f'unsupported image encoding {ENCODING!r}'
    }


def test_summary_csv_holds_escaped_names_and_defused_formulas(hostile_runs):
    root, _ = hostile_runs
    text = (root / 'a' / 'summary.csv').read_bytes().decode('utf-8')
    _assert_no_raw_controls(text.replace('\r\n', ''), 'summary.csv')
    rows = list(csv.DictReader(io.StringIO(text, newline='')))
    assert {r['topic'] for r in rows} - {'rig'} == {
        r'/cam\x1b]0;pwned\x07\x1b[2J',
        "'" + FORMULA_TOPIC,
    }
    for row in rows:  # numbers stay numbers
        assert float(row['throughput_fps']) > 0
        # the rig row (two camera topics) sums its cameras'
        assert int(row['skipped']) == (1 if row['topic'].startswith(('/cam', 'rig')) else 0)
        if row['backend'] == 'null':
            assert float(row['latency_ms_p50']) >= 0


def test_report_html_shows_names_and_labels_escaped(hostile_runs):
    root, _ = hostile_runs
    html = (root / 'a' / 'report.html').read_text(encoding='utf-8')
    _assert_no_raw_controls(html.replace('\n', ''), 'report.html')
    assert r'/cam\x1b]0;pwned\x07\x1b[2J' in html
    assert r'\x1b]0;red\x07red' in html  # a ground-truth / recorded label
    assert r'@SUM(A1)\u202eyellow\x9b2J' in html


def test_run_json_and_outputs_mcap_keep_the_true_names(hostile_runs):
    root, _ = hostile_runs
    run = json.loads((root / 'a' / 'run.json').read_text(encoding='utf-8'))
    assert {t['name'] for inp in run['inputs'] for t in inp['topics']} == {TOPIC, FORMULA_TOPIC}
    assert {s['topic'] for s in run['summary']} - {'rig'} == {TOPIC, FORMULA_TOPIC}
    assert any(repr(ENCODING) in reason for reason in run['skipped'])
    channel = detections_channel('recorded', TOPIC)
    with open_source(root / 'a' / 'outputs.mcap') as source:
        found = [decode_detections(raw) for raw in source.messages(topics=[channel])]
    assert found
    assert {gt.frame_id for gt in found} == {FRAME_ID}
    labels = {d.label for gt in found for d in gt.detections}
    assert labels
    assert labels <= set(LABELS.values())


# --- compare ---------------------------------------------------------------------------------


def test_compare_prints_warnings_and_writes_its_files_with_names_escaped(hostile_runs, tmp_path):
    root, _ = hostile_runs
    out = tmp_path / 'cmp'
    result = _cli('compare', str(root / 'a'), str(root / 'b'), '--out', str(out))
    assert result.returncode == 0, result.stderr
    _assert_no_raw_controls(result.stdout, 'stdout')
    _assert_no_raw_controls(result.stderr, 'stderr')
    assert visible(TOPIC) in result.stdout + result.stderr
    warnings = [line for line in result.stderr.splitlines() if 'warning' in line]
    assert any(visible(TOPIC) in line for line in warnings)  # fewer frames than the blocks need
    html = (out / 'comparison.html').read_text(encoding='utf-8')
    _assert_no_raw_controls(html.replace('\n', ''), 'comparison.html')
    assert r'/cam\x1b]0;pwned\x07\x1b[2J' in html
    text = (out / 'comparison.csv').read_bytes().decode('utf-8')
    _assert_no_raw_controls(text.replace('\r\n', ''), 'comparison.csv')
    topics = {row['topic'] for row in csv.DictReader(io.StringIO(text, newline=''))} - {'rig'}
    assert topics == {escape(TOPIC), "'" + FORMULA_TOPIC}


# --- the escaping itself ---------------------------------------------------------------------


def test_control_characters_are_written_as_python_escapes():
    assert visible('a\x1b[2Jb\x07\tc\nd\re\x00\x7f\x9b\u202e\u2028') == (
        r'a\x1b[2Jb\x07\tc\nd\re\x00\x7f\x9b\u202e\u2028'
    )
    assert visible('/camera/image_raw') == '/camera/image_raw'
    assert visible('ünïcode ✓ 日本') == 'ünïcode ✓ 日本'
    assert visible(r'C:\bags') == r'C:\bags'  # shown as it is
    assert escape(r'C:\bags') == r'C:\\bags'  # doubled where the text must read back
    assert visible_lines('one\x1b\ntwo\t') == 'one\\x1b\ntwo\\t'


def test_csv_cells_that_start_a_formula_get_an_apostrophe():
    for text in ('=1+2', '+1', '-2', '@SUM(A1)', "'quoted"):
        assert csv_text(text) == "'" + text
    assert csv_text('\tx') == r'\tx'  # TAB and CR are escaped, so no longer first
    assert csv_text('\rx') == r'\rx'
    assert csv_text('/camera/image_raw') == '/camera/image_raw'


def test_a_negative_number_stays_a_number_next_to_a_defused_topic(tmp_path):
    path = tmp_path / 'frames.csv'
    record = FrameRecord(
        input=0, backend='null', topic='-1', seq=3, log_time_ns=10, stamp_ns=-5,
        status='ok', note='', warmup=False, dropped=False, release_s=0.5,
    )  # fmt: skip
    with FramesCsvWriter(path) as writer:
        writer.write(record)
    with path.open(newline='') as handle:
        (row,) = list(csv.DictReader(handle))
    assert row['topic'] == "'-1"
    assert row['stamp_ns'] == '-5'
    assert read_frames_csv(path) == [record]


@given(st.text())
def test_escaping_reads_back_exactly(text):
    assert unescape(escape(text)) == text
    assert from_csv(csv_text(text)) == text
    for shown in (visible(text), escape(text), csv_text(text)):
        assert RAW.search(shown) is None
        assert not any(0xD800 <= ord(c) <= 0xDFFF for c in shown)
