"""Ground truth from COCO JSON and CVAT XML files, matched to frames by stamp or by seq."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.errors import SourceError, UsageError
from replaybench.results.groundtruth import (
    DEFAULT_TOLERANCE_NS,
    load_ground_truth_file,
    stamp_from_name,
)

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.types import Detection

T0 = 1_700_000_000_000_000_000
DT = 33_333_333
CAM = '/camera/image_raw'


def _coco(images: list[dict[str, Any]], annotations: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        'info': {'description': 'test'},
        'images': images,
        'annotations': annotations,
        'categories': [{'id': 1, 'name': 'red'}, {'id': 7, 'name': 'blue'}],
    }


def _write(tmp_path: Path, name: str, content: str | dict[str, Any]) -> Path:
    path = tmp_path / name
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    return path


def _boxes(dets: tuple[Detection, ...] | None) -> list[tuple[str, float, float, float, float]]:
    assert dets is not None
    return [(d.label, d.x0, d.y0, d.x1, d.y1) for d in dets]


# ---------------------------------------------------------------------------------------- COCO

COCO_BY_NAME = _coco(
    [
        {'id': 1, 'file_name': f'frames/frame_{T0}.png', 'width': 320, 'height': 240},
        {'id': 2, 'file_name': f'frames/frame_{T0 + DT}.png', 'width': 320, 'height': 240},
        {'id': 3, 'file_name': f'frames/frame_{T0 + 2 * DT}.png', 'width': 320, 'height': 240},
    ],
    [
        {'id': 10, 'image_id': 1, 'category_id': 1, 'bbox': [10, 20, 30, 40], 'iscrowd': 0},
        {'id': 11, 'image_id': 1, 'category_id': 7, 'bbox': [100.5, 0, 9.5, 10], 'area': 95},
        {'id': 12, 'image_id': 3, 'category_id': 7, 'bbox': [1, 2, 3, 4]},
    ],
)


def test_coco_boxes_are_matched_by_the_stamp_in_the_file_name(tmp_path: Path) -> None:
    gt = load_ground_truth_file(_write(tmp_path, 'gt.json', COCO_BY_NAME), match='stamp')
    assert gt.format == 'coco'
    assert len(gt) == 3
    assert _boxes(gt.lookup(CAM, 0, T0)) == [
        ('red', 10.0, 20.0, 40.0, 60.0),
        ('blue', 100.5, 0.0, 110.0, 10.0),
    ]
    assert [d.class_index for d in gt.lookup(CAM, 0, T0) or ()] == [1, 7]
    assert [d.score for d in gt.lookup(CAM, 0, T0) or ()] == [1.0, 1.0]
    # an annotated image without boxes is a frame with no objects, not a missing frame
    assert gt.lookup(CAM, 1, T0 + DT) == ()
    assert _boxes(gt.lookup(CAM, 2, T0 + 2 * DT)) == [('blue', 1.0, 2.0, 4.0, 6.0)]
    # a frame the file does not list is not annotated
    assert gt.lookup(CAM, 3, T0 + 3 * DT) is None
    assert gt.labels == ['blue', 'red']
    assert gt.topics == frozenset()


def test_stamps_match_within_the_tolerance_and_nearest_first(tmp_path: Path) -> None:
    path = _write(tmp_path, 'gt.json', COCO_BY_NAME)
    gt = load_ground_truth_file(path, match='stamp')
    assert gt.tolerance_ns == DEFAULT_TOLERANCE_NS
    assert _boxes(gt.lookup(CAM, 0, T0 + 900_000)) == _boxes(gt.lookup(CAM, 0, T0))
    assert gt.lookup(CAM, 0, T0 - 1_000_001) is None
    assert gt.lookup(CAM, 2, T0 + 2 * DT - 400) == gt.lookup(CAM, 2, T0 + 2 * DT)
    exact = load_ground_truth_file(path, match='stamp', tolerance_ns=0)
    assert exact.lookup(CAM, 0, T0 + 1) is None
    assert exact.lookup(CAM, 0, T0) is not None


def test_coco_stamp_ns_and_timestamp_fields_win_over_the_file_name(tmp_path: Path) -> None:
    doc = _coco(
        [
            {'id': 1, 'file_name': 'a_5.png', 'stamp_ns': T0},
            {'id': 2, 'file_name': 'b_6.png', 'stamp_ns': str(T0 + DT)},
            # seconds with all nine decimals are exact: no float rounding on the way
            {'id': 3, 'file_name': 'c_7.png', 'timestamp': 'SECONDS'},
        ],
        [{'image_id': i, 'category_id': 1, 'bbox': [i, i, 1, 1]} for i in (1, 2, 3)],
    )
    text = json.dumps(doc).replace('"SECONDS"', '1700000000.066666667')
    gt = load_ground_truth_file(_write(tmp_path, 'gt.json', text), match='stamp', tolerance_ns=0)
    assert _boxes(gt.lookup(CAM, 9, T0)) == [('red', 1.0, 1.0, 2.0, 2.0)]
    assert _boxes(gt.lookup(CAM, 9, T0 + DT)) == [('red', 2.0, 2.0, 3.0, 3.0)]
    assert _boxes(gt.lookup(CAM, 9, T0 + 66_666_667)) == [('red', 3.0, 3.0, 4.0, 4.0)]
    assert gt.lookup(CAM, 9, 5) is None


def test_coco_matched_by_seq_uses_the_image_id_minus_the_offset(tmp_path: Path) -> None:
    path = _write(tmp_path, 'gt.json', COCO_BY_NAME)
    gt = load_ground_truth_file(path, match='seq')
    assert gt.lookup(CAM, 1, 12345) == gt.lookup(CAM, 1, 0)
    assert _boxes(gt.lookup(CAM, 1, 0))[0] == ('red', 10.0, 20.0, 40.0, 60.0)
    assert gt.lookup(CAM, 0, 0) is None
    shifted = load_ground_truth_file(path, match='seq', seq_offset=1)
    assert shifted.lookup(CAM, 0, 0) == gt.lookup(CAM, 1, 0)
    assert shifted.lookup(CAM, 2, 0) == gt.lookup(CAM, 3, 0)
    assert shifted.lookup(CAM, 3, 0) is None


def test_topic_restriction_and_per_image_topics(tmp_path: Path) -> None:
    doc = _coco(
        [
            {'id': 0, 'file_name': 'l.png', 'topic': '/left/image', 'seq': 4},
            {'id': 1, 'file_name': 'r.png', 'topic': '/right/image', 'seq': 4},
            {'id': 2, 'file_name': 'any.png', 'seq': 5},
        ],
        [
            {'image_id': 0, 'category_id': 1, 'bbox': [0, 0, 2, 2]},
            {'image_id': 1, 'category_id': 7, 'bbox': [0, 0, 3, 3]},
            {'image_id': 2, 'category_id': 7, 'bbox': [0, 0, 4, 4]},
        ],
    )
    gt = load_ground_truth_file(_write(tmp_path, 'gt.json', doc), match='seq')
    assert gt.topics == {'/left/image', '/right/image'}
    assert _boxes(gt.lookup('/left/image', 4, 0)) == [('red', 0.0, 0.0, 2.0, 2.0)]
    assert _boxes(gt.lookup('/right/image', 4, 0)) == [('blue', 0.0, 0.0, 3.0, 3.0)]
    assert gt.lookup('/other', 4, 0) is None
    assert _boxes(gt.lookup('/other', 5, 0)) == [('blue', 0.0, 0.0, 4.0, 4.0)]
    left = gt.with_topic('/left/image')
    assert left.lookup('/right/image', 4, 0) is None
    assert left.lookup('/right/image', 5, 0) is None
    assert left.lookup('/left/image', 5, 0) == gt.lookup('/other', 5, 0)
    assert left.with_topic(None).lookup('/right/image', 4, 0) == gt.lookup('/right/image', 4, 0)


def test_crowd_regions_and_empty_boxes_are_left_out_with_a_warning(tmp_path: Path) -> None:
    doc = _coco(
        [{'id': 1, 'file_name': 'x.png'}],
        [
            {'image_id': 1, 'category_id': 1, 'bbox': [0, 0, 5, 5], 'iscrowd': 1},
            {'image_id': 1, 'category_id': 1, 'bbox': [0, 0, 0, 5]},
            {'image_id': 1, 'category_id': 7, 'bbox': [1, 1, 5, 5]},
        ],
    )
    gt = load_ground_truth_file(_write(tmp_path, 'gt.json', doc), match='seq')
    assert _boxes(gt.lookup(CAM, 1, 0)) == [('blue', 1.0, 1.0, 6.0, 6.0)]
    assert len(gt.warnings) == 2
    assert any('crowd' in w for w in gt.warnings)
    assert any('without area' in w for w in gt.warnings)


def test_names_carry_stamps_in_nanoseconds_or_decimal_seconds() -> None:
    assert stamp_from_name('frame_1700000000033333333.png') == 1_700_000_000_033_333_333
    assert stamp_from_name('a/b/1700000000.033333333.jpg') == 1_700_000_000_033_333_333
    assert stamp_from_name('1700000000.5.png') == 1_700_000_000_500_000_000
    assert stamp_from_name('cam0_000042') == 42
    assert stamp_from_name('left.png') is None


# ---------------------------------------------------------------------------------------- CVAT

CVAT_IMAGES = f"""<?xml version="1.0" encoding="utf-8"?>
<annotations>
  <version>1.1</version>
  <meta><task><id>3</id><name>t</name><size>3</size><mode>annotation</mode></task></meta>
  <image id="0" name="frame_{T0}.png" width="320" height="240">
    <box label="red" source="manual" occluded="0" xtl="10.00" ytl="20.00" xbr="40.00"
         ybr="60.00" z_order="0"></box>
    <box label="blue" source="manual" occluded="1" xtl="100.5" ytl="0" xbr="110" ybr="10"
         z_order="0"><attribute name="color">dark</attribute></box>
    <polygon label="red" points="1,1;5,1;5,5" occluded="0" z_order="0"></polygon>
  </image>
  <image id="1" name="frame_{T0 + DT}.png" width="320" height="240"></image>
  <image id="2" name="frame_{T0 + 2 * DT}.png" width="320" height="240">
    <box label="blue" occluded="0" xtl="0" ytl="0" xbr="20" ybr="10" rotation="90"></box>
  </image>
</annotations>
"""


def test_cvat_for_images_by_stamp_and_by_seq(tmp_path: Path) -> None:
    path = _write(tmp_path, 'annotations.xml', CVAT_IMAGES)
    by_stamp = load_ground_truth_file(path, match='stamp')
    by_seq = load_ground_truth_file(path, match='seq')
    assert by_stamp.format == by_seq.format == 'cvat-images'
    first = [('red', 10.0, 20.0, 40.0, 60.0), ('blue', 100.5, 0.0, 110.0, 10.0)]
    assert _boxes(by_stamp.lookup(CAM, 99, T0)) == first
    assert _boxes(by_seq.lookup(CAM, 0, 99)) == first
    assert by_stamp.lookup(CAM, 99, T0 + DT) == () == by_seq.lookup(CAM, 1, 99)
    assert by_seq.lookup(CAM, 3, 0) is None
    # a 20x10 box turned by 90 degrees about its centre (10, 5) covers 10x20
    (label, x0, y0, x1, y1) = _boxes(by_seq.lookup(CAM, 2, 0))[0]
    assert label == 'blue'
    assert (x0, y0, x1, y1) == pytest.approx((5.0, -5.0, 15.0, 15.0))
    assert any('polygon' in w for w in by_seq.warnings)


CVAT_VIDEO = """<?xml version="1.0" encoding="utf-8"?>
<annotations>
  <version>1.1</version>
  <meta><task><id>1</id><size>5</size><mode>interpolation</mode>
    <start_frame>0</start_frame><stop_frame>4</stop_frame></task></meta>
  <track id="0" label="red" source="manual">
    <box frame="0" keyframe="1" outside="0" occluded="0" xtl="1" ytl="2" xbr="11" ybr="12"
         z_order="0"></box>
    <box frame="1" keyframe="0" outside="0" occluded="0" xtl="2" ytl="2" xbr="12" ybr="12"
         z_order="0"></box>
    <box frame="2" keyframe="1" outside="1" occluded="0" xtl="2" ytl="2" xbr="12" ybr="12"
         z_order="0"></box>
  </track>
  <track id="1" label="green" source="manual">
    <box frame="1" keyframe="1" outside="0" occluded="0" xtl="50" ytl="60" xbr="70" ybr="90"
         z_order="0"></box>
    <box frame="2" keyframe="1" outside="1" occluded="0" xtl="50" ytl="60" xbr="70" ybr="90"
         z_order="0"></box>
  </track>
</annotations>
"""


def test_cvat_for_video_tracks_give_boxes_per_frame_by_seq(tmp_path: Path) -> None:
    path = _write(tmp_path, 'video.xml', CVAT_VIDEO)
    gt = load_ground_truth_file(path, match='seq')
    assert gt.format == 'cvat-video'
    assert len(gt) == 5  # the task's size, also frames after every track ended
    assert _boxes(gt.lookup(CAM, 0, 0)) == [('red', 1.0, 2.0, 11.0, 12.0)]
    assert sorted(_boxes(gt.lookup(CAM, 1, 0))) == [
        ('green', 50.0, 60.0, 70.0, 90.0),
        ('red', 2.0, 2.0, 12.0, 12.0),
    ]
    assert gt.lookup(CAM, 2, 0) == ()  # outside="1": the objects left the view
    assert gt.lookup(CAM, 4, 0) == ()
    assert gt.lookup(CAM, 5, 0) is None


def test_cvat_for_video_cannot_be_matched_by_stamp(tmp_path: Path) -> None:
    path = _write(tmp_path, 'video.xml', CVAT_VIDEO)
    with pytest.raises(UsageError, match=r'video\.xml.*match by seq'):
        load_ground_truth_file(path, match='stamp')


# ---------------------------------------------------------------------------------------- errors

GOOD_IMAGE = {'id': 1, 'file_name': 'f_1.png'}
GOOD_ANN = {'image_id': 1, 'category_id': 1, 'bbox': [0, 0, 1, 1]}


@pytest.mark.parametrize(
    ('content', 'message'),
    [
        ('{"images": [', r'invalid JSON \(line 1, column 13\)'),
        ('[1, 2]', 'not a COCO file'),
        ({'images': [], 'categories': []}, r'"annotations" is missing'),
        (_coco([GOOD_IMAGE], [{**GOOD_ANN, 'image_id': 2}]), r'annotations\[0\]: image_id 2'),
        (_coco([GOOD_IMAGE], [{**GOOD_ANN, 'category_id': 3}]), 'category_id 3 is not in'),
        (_coco([GOOD_IMAGE], [{**GOOD_ANN, 'bbox': [0, 0, 1]}]), r'bbox must be \[x, y'),
        (_coco([GOOD_IMAGE], [{**GOOD_ANN, 'bbox': [0, 'a', 1, 1]}]), 'must hold numbers'),
        (_coco([GOOD_IMAGE, GOOD_IMAGE], []), 'image id 1 appears twice'),
        (_coco([{'file_name': 'x.png'}], []), r'images\[0\]\.id must be an integer'),
        (_coco([{'id': 1, 'timestamp': 'soon'}], []), 'timestamp must be a number of seconds'),
        (_coco([{'id': 1, 'file_name': 'left.png'}], []), r'images\[0\] \(left.png\) has no stamp'),
        (('<annotations><image id="0" name="f_1.png"><box label="x" xtl="a" ytl="0" '
          'xbr="1" ybr="1"/></image></annotations>'), r"xtl='a' must be a number"),
        ('<annotations><image id="0"', r'invalid XML \(line 1'),
        ('<dataset/>', 'root element is <dataset>'),
        ('hello', 'expected COCO JSON, CVAT XML or MOT gt.txt'),
    ],
)  # fmt: skip
def test_malformed_files_give_one_clear_error_naming_the_file(
    tmp_path: Path, content: str | dict[str, Any], message: str
) -> None:
    path = _write(tmp_path, 'bad.json', content)
    with pytest.raises(SourceError, match=message) as info:
        load_ground_truth_file(path, match='stamp')
    assert str(info.value).startswith(f'{path}: ')
    assert '\n' not in str(info.value)


def test_duplicate_stamps_name_both_images(tmp_path: Path) -> None:
    doc = _coco([{'id': 1, 'file_name': 'a_5.png'}, {'id': 2, 'file_name': 'b_5.png'}], [])
    with pytest.raises(SourceError, match=r'images\[1\] \(b_5.png\) and images\[0\] \(a_5.png\)'):
        load_ground_truth_file(_write(tmp_path, 'gt.json', doc), match='stamp')


def test_missing_file_and_unknown_mode_are_usage_errors(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match='no such ground-truth file'):
        load_ground_truth_file(tmp_path / 'nope.json', match='seq')
    path = _write(tmp_path, 'gt.json', COCO_BY_NAME)
    with pytest.raises(UsageError, match='use stamp or seq'):
        load_ground_truth_file(path, match='frame')  # type: ignore[arg-type]
