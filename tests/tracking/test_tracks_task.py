"""The tracks task end to end on the tracking fixture (written here by its writer): ``replaybench
run --tracker``, the tracker rows beside their detector, the ids in outputs.mcap, the figures in
summary.csv, frames.csv, run.json and ``load_run``, the gate on them, tracker options, and bad
input refused in one line."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import replaybench as rb
from replaybench.backends import get_backend
from replaybench.backends.base import BackendOptions
from replaybench.decode.detections import decode_detections
from replaybench.errors import ReplaybenchError
from replaybench.fixtures.tracks import TrackScene, write_tracks_mcap
from replaybench.sinks.annotations import annotation_text
from replaybench.sinks.mcap_writer import detections_channel
from replaybench.sources import open_source
from replaybench.tracking.trackers import make_tracker
from replaybench.types import Detection

FIXTURES = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags'
TOPIC = '/camera/image_raw/compressed'
METRICS = (
    'hota', 'deta', 'assa', 'loca', 'idf1', 'idp', 'idr', 'mota', 'motp',
    'id_switches', 'fragmentations', 'mt', 'ml',
)  # fmt: skip


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        capture_output=True,
        text=True,
        check=False,
    )


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_tracks_mcap(tmp_path_factory.mktemp('tracks') / 'tracks.mcap')


@pytest.fixture(scope='module')
def tracked(bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('runs') / 'tracked'
    done = _cli(
        'run', str(bag), '--backend', 'hsv', '--tracker', 'iou', '--tracker', 'sort',
        '--tracker', 'bytetrack', '--annotations', '--no-report', '--out', str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return out


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as f:
        return list(csv.DictReader(f))


def _written(run: Path, backend: str, topic: str = TOPIC) -> list[tuple[Detection, ...]]:
    """The detections of ``backend`` in the run's outputs.mcap, in log-time order."""
    channel = detections_channel(backend, topic)
    with open_source(run / 'outputs.mcap') as source:
        return [decode_detections(raw).detections for raw in source.messages(topics=[channel])]


def test_the_fixture_hides_objects_behind_the_wall_and_keeps_their_ids() -> None:
    scene = TrackScene()
    seen: dict[str, list[int]] = {}
    for i in range(90):
        for det in scene.render(i)[1]:
            seen.setdefault(det.id, []).append(i)
    assert sorted(seen) == ['1', '2', '3', '4', '5', '6']
    gaps = {k: max(np.diff(v)) for k, v in seen.items()}
    assert gaps['3'] > 5
    assert gaps['4'] > 5  # hidden for frames, then seen again under the same id


def test_each_tracker_is_a_row_beside_its_detector(tracked: Path) -> None:
    rows = _rows(tracked / 'summary.csv')
    assert [r['backend'] for r in rows] == ['hsv', 'hsv+iou', 'hsv+sort', 'hsv+bytetrack']
    assert all(rows[0][m] == '' for m in METRICS)
    for row in rows[1:]:
        assert all(row[m] != '' for m in METRICS), row['backend']
        assert 0 < float(row['hota']) <= 1
        assert float(row['track_ms']) > 0
        assert row['map50'] != ''  # the tracks' boxes are scored as boxes too


def test_bytetrack_keeps_ids_through_the_crossings_better_than_sort_and_sort_than_iou(
    tracked: Path,
) -> None:
    idf1 = {r['backend']: float(r['idf1']) for r in _rows(tracked / 'summary.csv')[1:]}
    assert idf1['hsv+bytetrack'] >= idf1['hsv+sort'] > idf1['hsv+iou']


def test_the_figures_are_the_written_tracks_scored_against_the_bag_truth(
    tracked: Path, bag: Path
) -> None:
    from replaybench.tasks.tracks.recording import figures_of, score_sequence

    with open_source(bag) as source:
        truth = [
            decode_detections(raw).detections
            for raw in source.messages(topics=['/ground_truth/detections'])
        ]
    tracks = _written(tracked, 'hsv+sort')
    expected = figures_of(score_sequence(list(zip(truth, tracks, strict=True))))
    summary = json.loads((tracked / 'run.json').read_text())['summary']
    got = next(r for r in summary if r['backend'] == 'hsv+sort')['task_metrics']
    for name in METRICS:
        assert got[name] == pytest.approx(expected[name], abs=1e-12), name


def _retracked(run: Path, tracker: str, topic: str = TOPIC) -> list[list[str]]:
    """The ids a new tracker gives the detector row's boxes of ``topic``, frame by frame."""
    again = make_tracker(tracker)
    ids = []
    for dets in _written(run, 'hsv', topic):
        found = again.update(
            np.array([(d.x0, d.y0, d.x1, d.y1) for d in dets]).reshape(-1, 4),
            np.array([d.score for d in dets]),
        )
        ids.append([str(t.id) for t in found if t.detection is not None])
    return ids


def test_the_written_ids_are_the_tracker_run_over_the_detector_rows_boxes_in_replay_order(
    tracked: Path,
) -> None:
    tracks = _written(tracked, 'hsv+sort')
    assert len(tracks) == 90
    assert [[d.id for d in frame] for frame in tracks] == _retracked(tracked, 'sort')
    assert {d.id for frame in tracks for d in frame} >= {'1', '2', '3'}


def test_each_camera_has_a_tracker_of_its_own(tmp_path: Path) -> None:
    out = tmp_path / 'two'
    done = _cli(
        'run', str(FIXTURES / 'two_camera.mcap'), '--backend', 'hsv', '--tracker', 'bytetrack',
        '--no-report', '--out', str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    for camera in ('/cam_left/image_raw/compressed', '/cam_right/image_raw/compressed'):
        written = [[d.id for d in f] for f in _written(out, 'hsv+bytetrack', camera)]
        assert written == _retracked(out, 'bytetrack', camera)
        assert any(written)


def test_frames_csv_has_the_track_time_of_every_tracked_frame(tracked: Path) -> None:
    rows = _rows(tracked / 'frames.csv')
    times = [r['track_ms'] for r in rows if r['backend'] == 'hsv+bytetrack']
    assert len(times) == 90
    assert all(float(t) > 0 for t in times)
    assert all(r['track_ms'] == '' for r in rows if r['backend'] == 'hsv')


def test_load_run_and_the_terminal_table_show_the_tracking_figures(tracked: Path) -> None:
    run = rb.load_run(tracked)
    row = next(s for s in run.summary_rows if s.backend == 'hsv+bytetrack')
    assert row.metric('idf1') is not None
    assert row.metric('hota') == pytest.approx(row.task_metrics['hota'])  # type: ignore[index]
    assert next(s for s in run.summary_rows if s.backend == 'hsv').metric('hota') is None


def test_the_annotations_are_labelled_with_the_track_id() -> None:
    det = Detection(0, 'red', 0.93, 1, 2, 3, 4, '7')
    assert annotation_text(det) == '#7 red 0.93'
    assert annotation_text(det._replace(id='')) == 'red 0.93'


def test_the_gate_fails_iou_against_bytetrack_on_idf1(tracked: Path) -> None:
    done = _cli(
        'compare', str(tracked), '--baseline-backend', 'hsv+bytetrack', '--fail-if',
        'idf1 < -0.01', '--fail-if', 'hota < -0.01',
    )  # fmt: skip
    assert done.returncode == 1, done.stdout + done.stderr
    assert 'idf1' in done.stdout + done.stderr


def test_tracker_options_come_from_the_config_file_and_the_backend_options(
    tmp_path: Path,
) -> None:
    config = tmp_path / 'track.toml'
    config.write_text('[detector]\nmin_area = 40\n[tracker.sort]\nmax_age = 4\nmin_hits = 2\n')
    cls = get_backend('hsv+sort')
    made: Any = cls(BackendOptions(config=config, extra={'min_hits': '5'}))  # type: ignore[call-arg]
    assert (made.tracker.max_age, made.tracker.min_hits) == (4, 5)
    made.detector.open()
    assert made.detector.config.detector.min_area == 40
    made.detector.close()
    config.write_text('[tracker.sort]\nmax_agee = 4\n')
    with pytest.raises(ReplaybenchError, match="no option 'max_agee'"):
        cls(BackendOptions(config=config))  # type: ignore[call-arg]


def test_truth_without_ids_gives_box_figures_and_a_warning_but_no_tracking_figures(
    tmp_path: Path,
) -> None:
    out = tmp_path / 'ros1'
    done = _cli(
        'run', str(FIXTURES / 'rgb8.bag'), '--backend', 'hsv', '--tracker', 'sort',
        '--no-report', '--out', str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    why = 'hsv+sort on /camera/image_raw: no tracking metrics: its ground-truth boxes carry no ids'
    assert why in done.stderr
    row = _rows(out / 'summary.csv')[1]
    assert row['backend'] == 'hsv+sort'
    assert row['map50'] != ''
    assert all(row[m] == '' for m in METRICS)


@pytest.mark.parametrize(
    ('args', 'line'),
    [
        (
            ['--backend', 'hsv-seg', '--tracker', 'sort'],
            "backend 'hsv-seg+sort': a tracker needs a box backend; hsv-seg gives segmentation",
        ),
        (
            ['--backend', 'hsv', '--tracker', 'deepsort'],
            "--tracker 'deepsort': unknown tracker; known: iou, sort, bytetrack",
        ),
        (
            ['--backend', 'hsv+kalman'],
            "backend 'hsv+kalman': unknown tracker 'kalman'; known: iou, sort, bytetrack",
        ),
        (
            ['--backend', 'fast=hsv', '--tracker', 'sort'],
            (
                "--tracker over the instance --backend 'fast=hsv': give its tracked row as an "
                'instance of its own, --backend LABEL=NAME+TRACKER (docs/tracking.md)'
            ),
        ),
    ],
)
def test_a_tracker_that_cannot_run_is_refused_in_one_line(
    args: list[str], line: str, tmp_path: Path
) -> None:
    done = _cli('run', str(FIXTURES / 'jpeg.mcap'), *args, '--out', str(tmp_path / 'x'))
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f'replaybench: error: {line}']


def test_recorded_tracks_are_scored_as_tracks_without_a_flag_and_timed_from_the_bag(
    tmp_path: Path,
) -> None:
    out = tmp_path / 'live'
    done = _cli(
        'run', str(FIXTURES / 'live_tracks.mcap'), '--backend', 'recorded', '--no-report',
        '--out', str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    (row,) = _rows(out / 'summary.csv')
    assert all(row[m] != '' for m in METRICS)
    assert row['track_ms'] == ''  # the tracker ran on the robot: no time of it here
    assert float(row['pipeline_ms_p50']) >= 40  # the node's latency, from the log times
    from replaybench.fixtures.live import LIVE_TRACKS_TOPIC

    with open_source(FIXTURES / 'live_tracks.mcap') as source:
        recorded = [
            decode_detections(raw).detections for raw in source.messages(topics=[LIVE_TRACKS_TOPIC])
        ]
    assert all(d.id for frame in recorded for d in frame)


def test_a_detectors_recorded_boxes_stay_boxes() -> None:
    from replaybench.fixtures.live import LIVE_TOPIC

    with open_source(FIXTURES / 'live_detections.mcap') as source:
        found = [decode_detections(raw).detections for raw in source.messages(topics=[LIVE_TOPIC])]
    boxes = [d for frame in found for d in frame]
    assert boxes
    assert not any(d.id for d in boxes)


def test_the_reports_more_figures_hold_the_tracking_figures_of_the_tracked_rows(
    tracked: Path,
) -> None:
    from replaybench.report.taskviews import report_parts

    rows = rb.load_run(tracked).summary_rows
    parts = report_parts()
    assert 'hota' in [m.name for m in parts.main]
    found = [columns(rows) for columns in parts.more_columns]
    headings, cells = next(f for f in found if 'IDF1' in f[0])
    assert headings[:4] == ('DetA', 'AssA', 'LocA', 'IDF1')
    idf1 = headings.index('IDF1')
    assert cells[0][idf1] == '–'  # hsv: no tracks
    assert float(cells[3][idf1]) == pytest.approx(rows[3].metric('idf1'), abs=5e-4)
    assert cells[3][headings.index('IDSW')].isdigit()


def _mot_line(frame: int, det: Detection, cls: int, consider: int = 1) -> str:
    w, h = det.x1 - det.x0, det.y1 - det.y0
    return f'{frame},{det.id},{det.x0},{det.y0},{w},{h},{consider},{cls},1.0'


def test_a_mot_truth_file_scores_the_pedestrians_and_drops_the_tracks_on_distractors(
    tracked: Path, bag: Path, tmp_path: Path
) -> None:
    from replaybench.tasks.tracks.recording import figures_of, score_sequence

    scene = TrackScene()
    truth = [scene.render(i)[1] for i in range(90)]
    # object 6 a static person (a distractor), object 5 a car, object 4 marked not to consider
    classes = {'5': 3, '6': 7}
    lines = [
        _mot_line(i + 1, d, classes.get(d.id, 1), 0 if d.id == '4' else 1)
        for i, frame in enumerate(truth)
        for d in frame
    ]
    gt = tmp_path / 'gt.txt'
    gt.write_text('\n'.join(lines) + '\n')
    out = tmp_path / 'mot'
    done = _cli(
        'run', str(bag), '--backend', 'hsv+sort', '--ground-truth-file', str(gt),
        '--no-report', '--out', str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    got = json.loads((out / 'run.json').read_text())['summary'][0]['task_metrics']

    from replaybench.tracking.trackers import box_iou_xyxy

    def scored(frame: tuple[Detection, ...]) -> tuple[Detection, ...]:
        return tuple(d for d in frame if d.id in {'1', '2', '3'})

    def kept(frame: tuple[Detection, ...], tracks: tuple[Detection, ...]) -> tuple[Detection, ...]:
        on = [d for d in frame if d.id == '6']
        if not on or not tracks:
            return tracks
        iou = box_iou_xyxy(
            np.array([(d.x0, d.y0, d.x1, d.y1) for d in on]),
            np.array([(d.x0, d.y0, d.x1, d.y1) for d in tracks]),
        )
        return tuple(t for j, t in enumerate(tracks) if iou[0, j] < 0.5)

    tracks = _written(tracked, 'hsv+sort')  # the same tracker over the same frames
    frames = [(scored(tuple(t)), kept(tuple(t), d)) for t, d in zip(truth, tracks, strict=True)]
    expected = figures_of(score_sequence(frames))
    for name in METRICS:
        assert got[name] == pytest.approx(expected[name], abs=1e-12), name
    # the tracks on the static person are not counted against the tracker
    naive = figures_of(
        score_sequence([(scored(tuple(t)), d) for t, d in zip(truth, tracks, strict=True)])
    )
    assert got['idp'] > naive['idp']


def test_a_malformed_mot_line_is_refused_naming_it(bag: Path, tmp_path: Path) -> None:
    gt = tmp_path / 'gt.txt'
    gt.write_text('1,1,10,10,20,20,1,1,1.0\n2,1,ten,10,20,20,1,1,1.0\n')
    done = _cli(
        'run', str(bag), '--backend', 'hsv+sort', '--ground-truth-file', str(gt),
        '--out', str(tmp_path / 'x'),
    )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"replaybench: error: {gt}:2: column 3 is not a number: 'ten'"
    ]
