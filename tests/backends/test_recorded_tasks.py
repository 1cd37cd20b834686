"""The `recorded` backend on recorded tags (AprilTagDetectionArray) and label masks (Image).

The bags are the live fixtures, written with the real MCAP writer at known log times
(``replaybench.fixtures.live_tasks``): the recorded latencies, the tag metrics and the mIoU of
the recorded backend are checked against values computed here from the written messages.
"""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

import replaybench as rb
from replaybench.fiducials.msgs import decode_tag_array
from replaybench.fixtures.live_tasks import (
    LIVE_MASK_TOPIC,
    LIVE_TAG_TOPIC,
    mask_timings,
    tag_timings,
    write_live_mask_mcap,
    write_live_tag_mcap,
)
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.sources import open_source
from replaybench.tasks.segmentation.scoring import confusion, scores
from replaybench.tasks.tags.scoring import score_frame, tag_accuracy

if TYPE_CHECKING:
    from collections.abc import Iterator

    from replaybench.fixtures.live import LiveTiming

REPO = Path(__file__).resolve().parents[2]
TAG_FRAMES = 8
MASK_FRAMES = 24
TAG_SIZES = '0=0.16,3=0.1,14=0.2'


@pytest.fixture(scope='module')
def tag_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_live_tag_mcap(tmp_path_factory.mktemp('tags') / 'live_tags.mcap', TAG_FRAMES)


@pytest.fixture(scope='module')
def mask_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_live_mask_mcap(tmp_path_factory.mktemp('masks') / 'live_masks.mcap', MASK_FRAMES)


@pytest.fixture(scope='module')
def tag_run(tag_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('tagrun') / 'run'
    rb.run(tag_bag, backends=['recorded', 'apriltag'], out=out, tag_sizes=TAG_SIZES, report=False)
    return out


@pytest.fixture(scope='module')
def mask_run(mask_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('maskrun') / 'run'
    rb.run(
        mask_bag,
        backends=['recorded', 'hsv-seg'],
        out=out,
        recorded_topic=LIVE_MASK_TOPIC,
        report=False,
    )
    return out


def _rows(run: Path, backend: str = 'recorded') -> list[dict[str, str]]:
    with (run / 'frames.csv').open(newline='') as f:
        return [r for r in csv.DictReader(f) if r['backend'] == backend]


def _exact_latencies(rows: list[dict[str, str]], timings: list[LiveTiming], note: str) -> None:
    assert len(rows) == len(timings)
    for row, timing in zip(rows, timings, strict=True):
        if timing.output_log_ns is None:
            assert row['note'] == f'{note}; no recorded output for this frame'
            assert row['pipeline_ms'] == row['capture_to_output_ms'] == ''
            assert row['output_log_time_ns'] == ''
            continue
        assert row['note'] == note
        assert int(row['output_log_time_ns']) == timing.output_log_ns
        assert float(row['pipeline_ms']) == pytest.approx(
            (timing.output_log_ns - timing.image_log_ns) / 1e6, abs=5e-5
        )
        assert float(row['capture_to_output_ms']) == pytest.approx(
            (timing.output_log_ns - timing.stamp_ns) / 1e6, abs=5e-5
        )


def test_recorded_tags_get_the_exact_latencies_of_their_known_log_times(tag_run: Path) -> None:
    timings = tag_timings(TAG_FRAMES)
    assert any(t.output_log_ns is None for t in timings)
    _exact_latencies(_rows(tag_run), timings, 'recorded tags: latency not measured')
    run = rb.load_run(tag_run)
    row = next(s for s in run.summary_rows if s.backend == 'recorded')
    assert row.recorded_outputs == sum(t.output_log_ns is not None for t in timings)
    assert row.recorded_outputs_dropped == sum(t.output_log_ns is None for t in timings)
    info = next(b for b in run.backends if b.name == 'recorded').info
    assert info['topic'] == LIVE_TAG_TOPIC
    assert info['frames_without_recorded_tags'] == row.recorded_outputs_dropped
    assert 'tag detector' in info['latency']


def test_recorded_tag_metrics_equal_those_of_the_written_outputs_against_the_truth(
    tag_bag: Path, tag_run: Path
) -> None:
    with open_source(tag_bag) as source:
        truth = {
            (t.frame_id, t.stamp_ns): t.tags
            for t in map(decode_tag_array, source.messages(topics=['/ground_truth/tags']))
        }
        written = {
            (t.frame_id, t.stamp_ns): t.tags
            for t in map(decode_tag_array, source.messages(topics=[LIVE_TAG_TOPIC]))
        }
    # a frame without an output counts as no tags found, as a tag backend finding none
    frames = [score_frame(written.get(key, ()), tags) for key, tags in truth.items()]
    expected = tag_accuracy(frames)
    run = rb.load_run(tag_run)
    row = next(s for s in run.summary_rows if s.backend == 'recorded')
    assert row.tag_accuracy == expected
    assert expected.recall is not None
    assert expected.recall < 1.0  # the dropped frames and the covered tag 14 of frame 5
    for csv_row, score in zip(_rows(tag_run), frames, strict=True):
        assert int(csv_row['tags']) == score.found
        assert int(csv_row['tag_matched']) == score.columns()['tag_matched']


def test_recorded_tags_agree_with_the_replayed_apriltag_backend_in_the_run(tag_run: Path) -> None:
    run = rb.load_run(tag_run)
    [agreement] = run.agreement
    assert (agreement.backend_a, agreement.backend_b) == ('recorded', 'apriltag')
    assert agreement.frames == TAG_FRAMES
    recorded = next(s for s in run.summary_rows if s.backend == 'recorded')
    assert recorded.tag_accuracy is not None
    assert agreement.n_a == recorded.tag_accuracy.n_found
    # the node's tags are the truth's moved by under half a pixel: apriltag finds them all
    assert agreement.matched == agreement.n_a


def test_recorded_masks_get_the_exact_latencies_of_their_known_log_times(mask_run: Path) -> None:
    timings = mask_timings(MASK_FRAMES)
    assert any(t.output_log_ns is None for t in timings)
    _exact_latencies(_rows(mask_run), timings, 'recorded masks: latency not measured')
    run = rb.load_run(mask_run)
    # the mask topic is the recorded output, not a camera: only the image topic is replayed
    assert {s.topic for s in run.summary_rows} == {'/camera/image_raw/compressed'}
    info = next(b for b in run.backends if b.name == 'recorded').info
    assert info['frames_without_recorded_masks'] == sum(t.output_log_ns is None for t in timings)


def test_recorded_mask_miou_equals_that_of_the_written_masks_against_the_truth(
    mask_bag: Path, mask_run: Path
) -> None:
    from replaybench.decode import decode_image

    def masks(source, topic):
        out = {}
        for raw in source.messages(topics=[topic]):
            frame = decode_image(raw)
            out[(frame.frame_id, frame.stamp_ns)] = np.array(frame.image).reshape(
                frame.height, frame.width
            )
        return out

    with open_source(mask_bag) as source:
        truth = masks(source, '/ground_truth/labels')
        written = masks(source, LIVE_MASK_TOPIC)
    total = np.zeros((256, 256), dtype=np.int64)
    for key in truth:
        if key in written:
            total += confusion(written[key], truth[key])
    expected = scores(total)
    run = rb.load_run(mask_run)
    row = next(s for s in run.summary_rows if s.backend == 'recorded')
    assert row.segmentation is not None
    assert row.segmentation.frames == len(written) < MASK_FRAMES
    assert row.segmentation.miou == pytest.approx(expected.miou, rel=1e-12)
    assert row.segmentation.pixel_accuracy == pytest.approx(expected.pixel_accuracy, rel=1e-12)
    assert expected.miou is not None
    assert 0.5 < expected.miou < 1.0  # off by a pixel, small objects missed
    # a frame without a mask is neither scored as a mask nor as boxes
    assert row.accuracy is None
    for csv_row in _rows(mask_run):
        key = ('camera_optical_frame', int(csv_row['stamp_ns']))
        if key in written:
            frame = scores(confusion(written[key], truth[key]))
            assert float(csv_row['miou']) == pytest.approx(frame.miou, abs=5e-5)
        else:
            assert csv_row['miou'] == ''


def test_recorded_masks_agree_with_the_replayed_hsv_seg_backend_in_the_run(
    mask_run: Path,
) -> None:
    run = rb.load_run(mask_run)
    [agreement] = run.segmentation_agreement
    assert (agreement.backend_a, agreement.backend_b) == ('recorded', 'hsv_seg')
    assert agreement.frames == sum(t.output_log_ns is not None for t in mask_timings(MASK_FRAMES))
    assert agreement.miou is not None
    assert 0.5 < agreement.miou < 1.0


def test_compare_of_two_runs_with_recorded_tags_and_masks_works(
    tag_run: Path, mask_run: Path, tmp_path: Path
) -> None:
    for run in (tag_run, mask_run):
        comparison = rb.compare(
            run, run, fail_if=['miou < -0.01', 'tag_recall < -0.01'], out=tmp_path / run.parent.name
        )
        assert comparison.gate is not None
        verdicts = {g.condition: g.verdict for g in comparison.gate.results}
        assert 'failed' not in verdicts.values(), verdicts
        backends = {r.backend for r in comparison.rows}
        assert 'recorded' in backends


def test_an_image_topic_that_is_not_a_label_mask_is_refused_with_one_line_and_exit_2(
    tmp_path: Path,
) -> None:
    bag = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bag),
            '--backend',
            'recorded',
            '--recorded-topic',
            '/camera/image_raw',
            '--out',
            str(tmp_path / 'run'),
        ],
        capture_output=True,
        text=True,
        check=False,
        env={'PYTHONPATH': str(REPO), 'PATH': '/usr/bin:/bin'},
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    expected = (
        f'replaybench: error: {bag}: --recorded-topic /camera/image_raw holds rgb8 images, not '
        'label masks (mono8 or mono16 class ids): the recorded backend reads an Image topic as '
        'label masks'
    )
    assert lines == [expected]


def _bag_with_masks(path: Path, masks: list[np.ndarray], encoding: str) -> Path:
    """64x48 scene frames on /camera/image_raw and, 5 ms after each, ``masks[i]`` (in
    ``encoding``) on /seg/mask."""
    from replaybench.fixtures.scene import Scene
    from replaybench.fixtures.writer import FixtureMessage, write_ros2_mcap
    from replaybench.msgs import IMAGE, serialize_image

    scene = Scene((64, 48), 0, 3)

    def messages() -> Iterator[FixtureMessage]:
        for i, labels in enumerate(masks):
            stamp = 1_700_000_000 * 10**9 + i * 10**8
            bgr, _ = scene.render(i)
            yield FixtureMessage(
                stamp, '/camera/image_raw', IMAGE, serialize_image(stamp, 'cam', bgr, 'bgr8')
            )
            data = serialize_image(stamp, 'cam', labels, encoding)
            yield FixtureMessage(stamp + 5_000_000, '/seg/mask', IMAGE, data)

    return write_ros2_mcap(path, messages())


def test_a_mono16_mask_is_read_and_a_mask_with_ids_above_255_is_left_out_with_a_note(
    tmp_path: Path,
) -> None:
    masks = []
    for i in range(4):
        labels = np.full((48, 64), 2, dtype=np.uint16)
        labels[0, 0] = 300 if i == 3 else 1
        masks.append(labels)
    bag = _bag_with_masks(tmp_path / 'mono16.mcap', masks, 'mono16')
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['recorded'],
            out_dir=None,
            recorded_topic='/seg/mask',
            report=False,
        )
    )
    [warning] = outcome.run.inputs[0].warnings
    assert warning == (
        '/seg/mask: 1 recorded message(s) could not be read: a mask with class id 300: ids '
        'above 255 are not read'
    )
    info = outcome.run.backends[0].info
    assert info['frames_matched'] == 3
    assert info['frames_without_recorded_masks'] == 1
    assert [r.pipeline_ms for r in outcome.records] == [5, 5, 5, None]


def test_a_recorded_mask_of_another_size_than_its_image_stops_the_backend_with_one_line(
    tmp_path: Path,
) -> None:
    half = np.ones((24, 32), np.uint8)
    bag = _bag_with_masks(tmp_path / 'small_masks.mcap', [half, half], 'mono8')
    proc = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bag),
            '--backend',
            'recorded',
            '--recorded-topic',
            '/seg/mask',
            '--out',
            str(tmp_path / 'run'),
        ],
        capture_output=True,
        text=True,
        check=False,
        env={'PYTHONPATH': str(REPO), 'PATH': '/usr/bin:/bin'},
    )
    assert proc.returncode == 1
    [line] = proc.stderr.strip().splitlines()
    assert 'the recorded mask of /camera/image_raw #0 is 32x24, its image 64x48' in line
