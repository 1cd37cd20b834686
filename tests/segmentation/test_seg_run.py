"""A segmentation run end to end: fixture bags with ground-truth masks through the real
writers and readers, masks in outputs.mcap, scores in frames.csv, summary.csv and run.json."""

from __future__ import annotations

import csv
import json
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from replaybench.backends.base import BackendOptions
from replaybench.backends.hsv_seg import HsvSegBackend
from replaybench.errors import UsageError
from replaybench.fixtures.masks import MASK_CLASS_NAMES, MASK_TOPIC, semantic_labels
from replaybench.fixtures.scene import Scene
from replaybench.fixtures.writer import stamp_ns, write_mcap, write_rosbag2
from replaybench.msgs import typestore
from replaybench.replay.output import Discard
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.segmentation.palette import palette
from replaybench.tasks.segmentation.recording import Segmentation
from replaybench.tasks.segmentation.scoring import confusion, scores
from replaybench.types import Frame, LabelMask

if TYPE_CHECKING:
    from pathlib import Path

FRAMES = 6
SIZE = (160, 120)


def _config(bag: Path, out: Path | None, **changes: object) -> RunConfig:
    values: dict[str, object] = {
        'inputs': [bag],
        'backends': ['hsv-seg'],
        'out_dir': out,
        'warmup': 1,
        'report': False,
        'hash_inputs': False,
    }
    values.update(changes)
    return RunConfig(**values)  # type: ignore[arg-type]


def _expected(index: int) -> tuple[np.ndarray, np.ndarray]:
    """What hsv-seg gives on fixture frame ``index``, and the frame's ground truth."""
    scene = Scene(SIZE)
    image, _ = scene.render(index)
    frame = Frame('/camera/image_raw', index, 0, 0, 'cam', image, 'bgr8', 'bgr8')
    result = HsvSegBackend().detect(frame)
    assert result.mask is not None
    return result.mask.labels, semantic_labels(scene, index)


def _images(path: Path, topic: str) -> list[tuple[int, str, str, np.ndarray]]:
    """(stamp, frame_id, encoding, pixels) of the Image messages of a topic of an MCAP."""
    store = typestore()
    found = []
    with path.open('rb') as stream:
        for _, channel, message in make_reader(stream).iter_messages(topics=[topic]):
            msg: Any = store.deserialize_cdr(message.data, 'sensor_msgs/msg/Image')
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            channels = 3 if msg.encoding == 'rgb8' else 1
            pixels = np.asarray(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, channels)
            plane = pixels if channels == 3 else pixels[:, :, 0]
            found.append((stamp, msg.header.frame_id, msg.encoding, plane))
            assert channel.topic == topic
    return found


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_mcap(tmp_path_factory.mktemp('seg') / 'seg.mcap', FRAMES, SIZE, masks=True)


def test_fixture_bags_hold_the_exact_class_of_every_pixel(bag: Path) -> None:
    truth = _images(bag, MASK_TOPIC)
    assert len(truth) == FRAMES
    scene = Scene(SIZE)
    for index, (stamp, frame_id, encoding, labels) in enumerate(truth):
        assert (stamp, frame_id, encoding) == (stamp_ns(index), 'camera_optical_frame', 'mono8')
        assert np.array_equal(labels, semantic_labels(scene, index))
        image, boxes = scene.render(index)
        # every object pixel the renderer painted is in the mask with the object's class
        assert set(np.unique(labels).tolist()) <= set(range(len(MASK_CLASS_NAMES)))
        for box in boxes:
            inside = labels[int(box.y0) : int(box.y1), int(box.x0) : int(box.x1)]
            assert (inside == box.class_index + 1).any()
        assert image.shape[:2] == labels.shape
    with bag.open('rb') as stream:
        records = {m.name: m.metadata for m in make_reader(stream).iter_metadata()}
    assert json.loads(records['replaybench.segmentation']['class_names']) == list(MASK_CLASS_NAMES)


def test_masks_reach_the_mcap_pixel_for_pixel_with_the_frame_header(
    bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'run'
    run_benchmark(_config(bag, out, annotations=True))
    written = _images(out / 'outputs.mcap', '/replaybench/hsv_seg/camera/image_raw/labels')
    colour = _images(out / 'outputs.mcap', '/replaybench/hsv_seg/camera/image_raw/labels_rgb')
    assert len(written) == len(colour) == FRAMES
    for index, ((stamp, frame_id, encoding, labels), rgb) in enumerate(
        zip(written, colour, strict=True)
    ):
        assert (stamp, frame_id, encoding) == (stamp_ns(index), 'camera_optical_frame', 'mono8')
        expected, _ = _expected(index)
        assert np.array_equal(labels, expected)
        assert rgb[2] == 'rgb8'
        assert np.array_equal(rgb[3], palette()[expected])
    with (out / 'outputs.mcap').open('rb') as stream:
        records = {m.name: m.metadata for m in make_reader(stream).iter_metadata()}
    names = json.loads(records['replaybench.segmentation']['hsv_seg'])
    assert names == ['background', 'red', 'green', 'blue', 'yellow']


def test_scores_in_every_output_are_those_of_the_confusion_matrices(
    bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'run'
    outcome = run_benchmark(_config(bag, out))
    with (out / 'frames.csv').open(newline='', encoding='utf-8') as file:
        rows = list(csv.DictReader(file))
    total = np.zeros((256, 256), dtype=np.int64)
    for index, row in enumerate(rows):
        predicted, truth = _expected(index)
        matrix = confusion(predicted, truth)
        total += matrix
        expected = scores(matrix)
        assert float(row['miou']) == pytest.approx(expected.miou, abs=5e-5)
        assert float(row['pixel_accuracy']) == pytest.approx(expected.pixel_accuracy, abs=5e-5)
        assert row['detections'] == '0'
    overall = scores(total)
    assert overall.miou is not None
    assert 0.5 < overall.miou < 1.0
    with (out / 'summary.csv').open(newline='', encoding='utf-8') as file:
        (summary,) = list(csv.DictReader(file))
    assert float(summary['miou']) == pytest.approx(overall.miou, abs=5e-5)
    document = json.loads((out / 'run.json').read_text(encoding='utf-8'))
    (entry,) = document['summary']
    segmentation = entry['segmentation']
    assert segmentation['frames'] == FRAMES
    assert segmentation['miou'] == pytest.approx(overall.miou)
    assert segmentation['pixel_accuracy'] == pytest.approx(overall.pixel_accuracy)
    assert segmentation['iou'] == pytest.approx(
        {MASK_CLASS_NAMES[c]: v for c, v in overall.iou.items()}
    )
    assert entry['accuracy'] is None  # the detections ground truth is not a mask's
    model = outcome.run.summary_rows[0]
    assert model.segmentation is not None
    assert model.segmentation.miou == pytest.approx(overall.miou)


def test_a_folder_of_png_masks_scores_as_the_topic_does(bag: Path, tmp_path: Path) -> None:
    folder = tmp_path / 'masks'
    folder.mkdir()
    for stamp, _, _, labels in _images(bag, MASK_TOPIC):
        cv2.imwrite(str(folder / f'{stamp}.png'), labels)
    by_topic = run_benchmark(_config(bag, None)).summaries[0].segmentation
    by_folder = run_benchmark(_config(bag, None, ground_truth_masks=str(folder)))
    assert by_folder.summaries[0].segmentation == by_topic


def test_a_rosbag2_with_masks_is_scored_and_its_mask_topic_is_not_replayed(
    tmp_path: Path,
) -> None:
    bag = write_rosbag2(tmp_path / 'bag', FRAMES, SIZE, masks=True)
    outcome = run_benchmark(_config(bag, None))
    assert {r.topic for r in outcome.records} == {'/camera/image_raw'}
    segmentation = outcome.summaries[0].segmentation
    assert segmentation is not None
    assert segmentation.frames == FRAMES


def test_a_missing_mask_topic_or_an_empty_folder_is_one_clear_error(
    bag: Path, tmp_path: Path
) -> None:
    with pytest.raises(UsageError, match='ground-truth mask topic /masks is not an image topic'):
        run_benchmark(_config(bag, None, ground_truth_masks='/masks'))
    (tmp_path / 'empty').mkdir()
    with pytest.raises(UsageError, match='no ground-truth masks'):
        run_benchmark(_config(bag, None, ground_truth_masks=str(tmp_path / 'empty')))


def test_two_segmentation_backends_are_compared_with_each_other() -> None:
    state = Segmentation(2)
    labels = np.array([[0, 1], [1, 1]], dtype=np.uint8)
    other = np.array([[0, 1], [0, 1]], dtype=np.uint8)
    key = ('/cam', 0, 0, 1, 'f')
    state.add(Discard(), 'a', 0, None, key, LabelMask(labels, ('bg', 'x')))
    state.add(Discard(), 'b', 0, None, key, LabelMask(other, ('bg', 'x')))
    (row,) = state.agreements()
    # b against a: class 0 hits 1, union 2 -> 0.5; class 1 hits 2, union 3 -> 2/3
    assert row['frames'] == 1
    assert row['miou'] == pytest.approx((0.5 + 2 / 3) / 2)
    assert row['pixel_agreement'] == pytest.approx(0.75)


def test_a_run_with_two_segmentation_backends_records_their_agreement(bag: Path) -> None:
    def factory(name: str, options: BackendOptions) -> HsvSegBackend:
        # the second cleans its masks with a larger kernel: close to the first, not equal
        extra = {'kernel': '9'} if name == 'wide' else {}
        return HsvSegBackend(replace(options, extra=extra))

    outcome = run_benchmark(
        _config(bag, None, backends=['hsv-seg', 'wide']), backend_factory=factory
    )
    (row,) = outcome.run.segmentation_agreement
    assert (row.backend_a, row.backend_b, row.topic, row.frames) == (
        'hsv_seg',
        'wide',
        '/camera/image_raw',
        FRAMES,
    )
    total = np.zeros((256, 256), dtype=np.int64)
    wide = HsvSegBackend(BackendOptions(extra={'kernel': '9'}))
    for index in range(FRAMES):
        first, _ = _expected(index)
        image, _ = Scene(SIZE).render(index)
        mask = wide.detect(Frame('/c', index, 0, 0, 'c', image, 'bgr8', 'bgr8')).mask
        assert mask is not None
        total += confusion(mask.labels, first, ignore=None)
    expected = scores(total)
    assert row.miou == pytest.approx(expected.miou)
    assert row.pixel_agreement == pytest.approx(expected.pixel_accuracy)
    assert row.miou is not None
    assert 0.5 < row.miou < 1.0


def test_compare_gates_on_miou_with_the_cli(bag: Path, tmp_path: Path) -> None:
    import subprocess
    import sys

    from replaybench.backends.hsv import DetectorParams, HsvConfig, config_to_toml

    # a candidate whose opening (kernel 15) erases the small objects: a clearly lower mIoU
    worse = tmp_path / 'worse.toml'
    worse.write_text(config_to_toml(HsvConfig(detector=DetectorParams(kernel=15))), 'utf-8')
    base, cand = tmp_path / 'base', tmp_path / 'cand'
    run_benchmark(_config(bag, base))
    run_benchmark(_config(bag, cand, options=BackendOptions(config=worse)))

    def compare(*extra: str) -> subprocess.CompletedProcess[str]:
        command = [sys.executable, '-m', 'replaybench', 'compare', str(base), str(cand), *extra]
        return subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)

    failed = compare('--fail-if', 'miou < -0.01', '--out', str(tmp_path / 'cmp'))
    assert failed.returncode == 1, failed.stderr
    assert 'miou' in failed.stdout + failed.stderr
    passed = compare('--fail-if', 'miou < -0.9')
    assert passed.returncode == 0, passed.stdout + passed.stderr
    document = json.loads((tmp_path / 'cmp' / 'comparison.json').read_text(encoding='utf-8'))
    (row,) = [r for r in document['rows'] if r['role'] == 'candidate']
    base_miou = json.loads((base / 'run.json').read_text('utf-8'))['summary'][0]['miou']
    cand_miou = json.loads((cand / 'run.json').read_text('utf-8'))['summary'][0]['miou']
    assert row['metrics']['miou']['diff'] == pytest.approx(cand_miou - base_miou)
    assert cand_miou < base_miou - 0.01


def test_two_runs_write_the_same_masks_byte_for_byte(bag: Path, tmp_path: Path) -> None:
    first, second = tmp_path / 'a', tmp_path / 'b'
    for out in (first, second):
        run_benchmark(_config(bag, out, backends=['hsv-seg', 'onnx-seg'], annotations=True))
    assert (first / 'outputs.mcap').read_bytes() == (second / 'outputs.mcap').read_bytes()
    columns = ('backend', 'seq', 'miou', 'pixel_accuracy')
    rows = []
    for out in (first, second):
        with (out / 'frames.csv').open(newline='', encoding='utf-8') as file:
            rows.append([tuple(r[c] for c in columns) for r in csv.DictReader(file)])
    assert rows[0] == rows[1]
    assert {r[0] for r in rows[0]} == {'hsv_seg', 'onnx_seg'}
