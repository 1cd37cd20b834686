"""run_benchmark with --ground-truth-file, --annotations and --copy-images."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from replaybench.decode import decode_detections, decode_image
from replaybench.errors import UsageError
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.sources import open_source

BAG = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'two_camera.mcap'
LEFT = '/cam_left/image_raw/compressed'


def _coco_from_bag(path: Path, topic: str, id_base: int = 0) -> None:
    """The bag's ground-truth topic for one camera as COCO, stamps in the file names."""
    images: list[dict[str, Any]] = []
    annotations: list[dict[str, Any]] = []
    categories: dict[str, int] = {}
    with open_source(BAG) as source:
        truth = {}
        for raw in source.messages(topics=['/ground_truth/detections']):
            gt = decode_detections(raw)
            truth[(gt.frame_id, gt.stamp_ns)] = gt.detections
        for raw in source.messages(topics=[topic]):
            image = decode_image(raw)
            image_id = raw.seq + id_base
            images.append({'id': image_id, 'file_name': f'frame_{image.stamp_ns}.png'})
            for det in truth[(image.frame_id, image.stamp_ns)]:
                cid = categories.setdefault(det.label, len(categories) + 1)
                box = [det.x0, det.y0, det.x1 - det.x0, det.y1 - det.y0]
                annotations.append({'image_id': image_id, 'category_id': cid, 'bbox': box})
    cats = [{'id': i, 'name': n} for n, i in categories.items()]
    path.write_text(json.dumps({'images': images, 'annotations': annotations, 'categories': cats}))


def _accuracy(outcome) -> dict[str, Any]:
    return {s.topic: s.accuracy for s in outcome.summaries if s.backend == 'hsv'}


@pytest.mark.parametrize(('match', 'id_base'), [('stamp', 7), ('seq', 0), ('seq', 1)])
def test_a_coco_file_scores_like_the_ground_truth_topic(
    tmp_path: Path, match: str, id_base: int
) -> None:
    gt = tmp_path / 'gt.json'
    _coco_from_bag(gt, LEFT, id_base)
    from_topic = run_benchmark(RunConfig(inputs=[BAG], backends=['hsv'], out_dir=tmp_path / 'a'))
    from_file = run_benchmark(
        RunConfig(
            inputs=[BAG],
            backends=['hsv'],
            out_dir=tmp_path / 'b',
            ground_truth_file=gt,
            ground_truth_match=match,
            ground_truth_image_topic=LEFT,
            ground_truth_seq_offset=id_base,
        )
    )
    assert _accuracy(from_file)[LEFT] == _accuracy(from_topic)[LEFT]
    assert _accuracy(from_file)[LEFT].frames == 10
    assert _accuracy(from_file)['/cam_right/image_raw/compressed'] is None
    settings = from_file.run.settings
    assert (settings.ground_truth_file, settings.ground_truth_match) == (str(gt), match)


def test_a_file_that_does_not_name_its_topic_needs_one_with_two_cameras(tmp_path: Path) -> None:
    gt = tmp_path / 'gt.json'
    _coco_from_bag(gt, LEFT)
    with pytest.raises(UsageError, match='--ground-truth-image-topic'):
        run_benchmark(
            RunConfig(inputs=[BAG], backends=['hsv'], out_dir=tmp_path / 'a', ground_truth_file=gt)
        )
    assert not (tmp_path / 'a').exists()


def test_annotations_and_copied_images_land_in_outputs_mcap(tmp_path: Path) -> None:
    out = tmp_path / 'run'
    run_benchmark(
        RunConfig(
            inputs=[BAG],
            backends=['hsv', 'null'],
            out_dir=out,
            annotations=True,
            copy_images=True,
            max_frames=4,
        )
    )
    with (out / 'outputs.mcap').open('rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    assert summary.statistics is not None
    counts = {
        summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()
    }
    assert counts[LEFT] == counts['/cam_right/image_raw/compressed'] == 4
    assert counts['/replaybench/hsv/cam_left/image_raw/compressed/annotations'] == 4
    assert counts['/replaybench/null/cam_right/image_raw/compressed/annotations'] == 4
