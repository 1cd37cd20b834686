"""Model spec: family from shapes and metadata, preprocessing keys, class names, ONNX graphs."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from detector.onnxgraph import Output, write_model

from replaybench.detector.labels import COCO80, parse_names, read_labels_file, resolve_labels
from replaybench.detector.spec import (
    AMBIGUOUS,
    Preprocess,
    default_preprocess,
    family_from_shapes,
    grid_points,
    load_model_spec,
    looks_raw_grid,
    preprocess_overrides,
)
from replaybench.errors import BackendError


def test_grid_points_count_cells_over_the_three_strides():
    assert grid_points((416, 416)) == 52 * 52 + 26 * 26 + 13 * 13 == 3549
    assert grid_points((640, 640)) == 8400
    assert grid_points((64, 32)) == 42


@pytest.mark.parametrize(
    ('shapes', 'size', 'family'),
    [
        ([(1, 3549, 85)], (416, 416), AMBIGUOUS),  # YOLOX-Nano / anchor-free decoded
        ([(1, 8400, 85)], (640, 640), AMBIGUOUS),
        ([(1, 25200, 85)], (640, 640), 'yolov5'),  # 3 anchors per cell
        ([(1, 84, 8400)], (640, 640), 'yolov8'),
        ([(1, 8, 3549)], (416, 416), 'yolov8'),  # 4 classes
        ([(1, 300, 6)], (640, 640), 'nms'),  # Ultralytics nms=True / YOLOv10
        ([(1, 100, 7)], (640, 640), 'nms'),
        ([('N', 7)], (640, 640), 'nms'),  # YOLOv7 end2end (onnxruntime NMS)
        ([(100, 6)], (640, 640), 'nms'),
        ([(1, 1), (1, 100, 4), (1, 100), (1, 100)], (640, 640), 'nms'),  # EfficientNMS
        ([(1, 'K', 4), (1, 'K'), (1, 'K')], (640, 640), 'nms'),
        ([(1, 6300, 85)], (512, 480), 'yolov5'),  # not a grid count: longer axis = candidates
        ([(1, 85, 5000)], (512, 480), 'yolov8'),
        ([(1, 'N', 85)], (640, 640), 'yolov5'),
        ([(1, 84, 'N')], (640, 640), 'yolov8'),
        ([(1, 3, 4, 4)], (640, 640), None),
        ([(1, 116, 8400), (1, 32, 160, 160)], (640, 640), None),  # segmentation
        ([(1, 5)], (640, 640), None),
    ],
)
def test_family_from_output_shapes(shapes, size, family):
    assert family_from_shapes(shapes, [f'o{i}' for i in range(len(shapes))], size) == family


def test_raw_yolox_rows_are_told_from_decoded_boxes():
    size = (64, 32)
    raw = np.zeros((42, 7), np.float32)
    raw[:, :2] = np.linspace(-0.5, 1.5, 42)[:, None]
    raw[:, 2:4] = 0.5
    assert looks_raw_grid(raw, size)
    raw[3, 3] = -0.1  # a negative log-size is never a decoded size
    assert looks_raw_grid(raw, size)
    decoded = np.zeros((42, 7), np.float32)
    decoded[:, 0] = np.linspace(4, 60, 42)
    decoded[:, 2:4] = 8
    assert not looks_raw_grid(decoded, size)


def test_family_defaults_follow_the_reference_exports():
    yolox = default_preprocess('yolox', (416, 416))
    assert (yolox.channel_order, yolox.scale, yolox.pad_value, yolox.align) == (
        'bgr',
        1.0,
        114,
        'topleft',
    )
    for family in ('yolov5', 'yolov8', 'nms'):
        pre = default_preprocess(family, (640, 640))
        assert (pre.channel_order, pre.scale, pre.pad_value, pre.align) == (
            'rgb',
            1 / 255,
            114,
            'center',
        )
        assert pre.letterbox
        assert pre.mean == (0, 0, 0)
        assert pre.std == (1, 1, 1)


def test_preprocess_keys_are_parsed_from_strings():
    pre = preprocess_overrides(
        Preprocess(size=(32, 32)),
        {
            'channel_order': 'BGR',
            'scale': '1/255',
            'pad_value': '0',
            'letterbox_align': 'centre',
            'mean': '0.5,0.5,0.5',
            'std': '0.25',
            'letterbox': 'false',
        },
        'test',
    )
    assert pre == Preprocess(
        size=(32, 32),
        letterbox=False,
        pad_value=0,
        channel_order='bgr',
        scale=1 / 255,
        mean=(0.5, 0.5, 0.5),
        std=(0.25, 0.25, 0.25),
        align='center',
    )
    assert preprocess_overrides(pre, {'scale': '0.5', 'letterbox_align': 'top-left'}, 't') == (
        Preprocess(
            size=(32, 32),
            letterbox=False,
            pad_value=0,
            channel_order='bgr',
            scale=0.5,
            mean=(0.5, 0.5, 0.5),
            std=(0.25, 0.25, 0.25),
            align='topleft',
        )
    )


@pytest.mark.parametrize(
    ('key', 'value', 'message'),
    [
        ('channel_order', 'bgra', 'channel_order must be bgr or rgb'),
        ('scale', '-1', 'scale must be a positive number'),
        ('scale', '1/0', 'scale must be a positive number'),
        ('pad_value', '300', 'pad_value must be an integer 0..255'),
        ('letterbox_align', 'bottom', 'letterbox_align must be topleft or center'),
        ('std', '1,0,1', 'std must not be 0'),
        ('mean', '1,2', 'mean must be one or three numbers'),
    ],
)
def test_bad_preprocess_values_are_refused_with_the_key(key, value, message):
    with pytest.raises(BackendError, match=f'where: {message}'):
        preprocess_overrides(Preprocess(size=(8, 8)), {key: value}, 'where')


def test_names_metadata_as_a_comma_list():
    assert parse_names('red,green, blue ,yellow') == ('red', 'green', 'blue', 'yellow')


def test_names_metadata_as_an_ultralytics_dict_string():
    assert parse_names("{0: 'person', 1: 'bicycle', 2: 'car'}") == ('person', 'bicycle', 'car')
    assert parse_names("{1: 'b', 0: 'a'}") == ('a', 'b')
    assert parse_names('["a", "b"]') == ('a', 'b')


@pytest.mark.parametrize(
    ('text', 'message'),
    [
        ("{0: 'a', 2: 'c'}", r'class indices must be 0\.\.1'),
        ("{'a': 0}", 'dict keys must be class indices'),
        ('{0: ', 'not a valid list or dict literal'),
        ('a,,b', 'empty name'),
        ('[1, 2]', 'non-empty strings'),
        ('', 'empty class names'),
    ],
)
def test_bad_names_metadata_is_refused(text, message):
    with pytest.raises(BackendError, match=message):
        parse_names(text)


def test_labels_file_has_one_name_per_line(tmp_path):
    path = tmp_path / 'labels.txt'
    path.write_text('# my classes\ncat\n\ndog house\n  bird  \n', encoding='utf-8')
    assert read_labels_file(path) == ('cat', 'dog house', 'bird')
    (tmp_path / 'empty.txt').write_text('\n', encoding='utf-8')
    with pytest.raises(BackendError, match='no class names'):
        read_labels_file(tmp_path / 'empty.txt')
    with pytest.raises(BackendError, match='cannot read labels file'):
        read_labels_file(tmp_path / 'missing.txt')


def test_labels_option_beats_metadata_and_counts_must_match(tmp_path):
    path = tmp_path / 'labels.txt'
    path.write_text('a\nb\n', encoding='utf-8')
    assert resolve_labels(str(path), 'x,y', 2) == (('a', 'b'), f'file {path}')
    assert resolve_labels('coco', 'x,y', 80) == (COCO80, 'coco')
    assert resolve_labels(None, 'x,y', 2) == (('x', 'y'), 'model metadata')
    assert resolve_labels(None, None, 80)[0] == COCO80
    assert resolve_labels(None, None, 3)[0] == ('class0', 'class1', 'class2')
    assert resolve_labels(None, None, None)[0] == ()
    with pytest.raises(BackendError, match='2 class names but the model outputs 3 classes'):
        resolve_labels(str(path), None, 3)
    with pytest.raises(BackendError, match='coco: 80 class names but the model outputs 4 classes'):
        resolve_labels('coco', None, 4)


def test_coco80_is_the_yolo_class_list():
    assert len(COCO80) == 80
    assert (COCO80[0], COCO80[15], COCO80[79]) == ('person', 'cat', 'toothbrush')


# --- ONNX graphs read by onnxruntime -------------------------------------------------------


def _v8_output(classes: int = 4) -> np.ndarray:
    return np.zeros((1, 4 + classes, 42), np.float32)


def test_a_yolov8_model_is_read_with_its_metadata(tmp_path):
    path = write_model(
        tmp_path / 'blobs.onnx',
        [Output('output0', _v8_output())],
        input_shape=(1, 3, 32, 64),
        metadata={
            'replaybench.family': 'yolov8',
            'names': 'red,green,blue,yellow',
            'replaybench.channel_order': 'bgr',
            'replaybench.scale': '0.00392156862745098',
            'replaybench.pad_value': '0',
            'replaybench.letterbox_align': 'topleft',
        },
    )
    spec = load_model_spec(path)
    assert spec.family == 'yolov8'
    assert spec.family_source == 'metadata'
    assert spec.class_names == ('red', 'green', 'blue', 'yellow')
    assert spec.labels_source == 'model metadata'
    assert spec.input_name == 'images'
    assert spec.output_names == ('output0',)
    assert spec.precision == 'fp32'
    assert spec.preprocess == Preprocess(
        size=(64, 32), pad_value=0, channel_order='bgr', scale=1 / 255, align='topleft'
    )
    assert spec.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert spec.metadata['names'] == 'red,green,blue,yellow'


def test_the_family_option_beats_metadata_and_metadata_beats_shapes(tmp_path):
    # [1, 42, 9] on a 64x32 input: shapes alone say "yolox or yolov5"
    rows = np.zeros((1, 42, 9), np.float32)
    path = write_model(
        tmp_path / 'm.onnx',
        [Output('output', rows)],
        input_shape=(1, 3, 32, 64),
        metadata={'replaybench.family': 'yolov5'},
    )
    spec = load_model_spec(path)
    assert (spec.family, spec.family_source) == ('yolov5', 'metadata')
    spec = load_model_spec(path, family='yolox')
    assert (spec.family, spec.family_source) == ('yolox', 'option')
    assert spec.preprocess.channel_order == 'bgr'
    assert spec.preprocess.scale == 1.0
    assert spec.class_names == ('class0', 'class1', 'class2', 'class3')


def test_an_ambiguous_grid_output_is_probed_for_raw_offsets(tmp_path):
    raw = np.zeros((1, 42, 7), np.float32)
    raw[0, :, 2:4] = -0.25  # log-sizes: raw YOLOX head
    path = write_model(tmp_path / 'raw.onnx', [Output('output', raw)], input_shape=(1, 3, 32, 64))
    spec = load_model_spec(path)
    assert spec.family == 'yolox'
    assert spec.family_source == 'output shape + probe (raw grid)'
    assert spec.preprocess.align == 'topleft'

    decoded = np.zeros((1, 42, 7), np.float32)
    decoded[0, :, 0] = np.linspace(4, 60, 42)
    decoded[0, :, 2:4] = 8
    path = write_model(
        tmp_path / 'dec.onnx', [Output('output', decoded)], input_shape=(1, 3, 32, 64)
    )
    spec = load_model_spec(path)
    assert spec.family == 'yolov5'
    assert spec.family_source == 'output shape + probe (decoded boxes)'


def test_an_nms_model_runs_all_its_outputs(tmp_path):
    path = write_model(
        tmp_path / 'nms.onnx',
        [
            Output('num_dets', np.array([[1]], np.int32)),
            Output('det_boxes', np.zeros((1, 10, 4), np.float32)),
            Output('det_scores', np.zeros((1, 10), np.float32)),
            Output('det_classes', np.zeros((1, 10), np.int32)),
        ],
    )
    spec = load_model_spec(path, labels='coco')
    assert (spec.family, spec.family_source) == ('nms', 'output shapes')
    assert spec.output_names == ('num_dets', 'det_boxes', 'det_scores', 'det_classes')
    assert spec.class_names == COCO80
    assert spec.preprocess == default_preprocess('nms', (32, 32))


def test_a_labels_file_must_match_the_class_count(tmp_path):
    path = write_model(
        tmp_path / 'm.onnx', [Output('o', _v8_output(3))], input_shape=(1, 3, 32, 64)
    )
    labels = tmp_path / 'l.txt'
    labels.write_text('a\nb\nc\n', encoding='utf-8')
    assert load_model_spec(path, labels=str(labels)).class_names == ('a', 'b', 'c')
    labels.write_text('a\nb\n', encoding='utf-8')
    with pytest.raises(BackendError, match='2 class names but the model outputs 3 classes'):
        load_model_spec(path, labels=str(labels))


def test_fp16_inputs_and_dynamic_sizes_are_read(tmp_path):
    path = write_model(
        tmp_path / 'm.onnx',
        [Output('o', np.zeros((1, 8, 42), np.float32))],
        input_shape=('batch', 3, 'height', 'width'),
        input_dtype=np.float16,
        metadata={'imgsz': '[32, 64]'},
    )
    spec = load_model_spec(path)
    assert spec.precision == 'fp16'
    assert spec.preprocess.size == (64, 32)  # Ultralytics imgsz is [h, w]
    assert spec.input_shape == ('batch', 3, 'height', 'width')
    spec = load_model_spec(path, overrides={'size': '64x32', 'pad_value': '0'})
    assert spec.preprocess.size == (64, 32)
    assert spec.preprocess.pad_value == 0


@pytest.mark.parametrize(
    ('kwargs', 'message'),
    [
        ({'input_shape': (1, 32, 32, 3)}, r'expected an NCHW image \[1, 3, H, W\]'),
        ({'input_shape': (4, 3, 32, 32)}, 'input batch is fixed at 4'),
        ({'input_dtype': np.uint8}, r'input type tensor\(uint8\) is not supported'),
    ],
)
def test_unusable_inputs_are_refused(tmp_path, kwargs, message):
    path = write_model(
        tmp_path / 'm.onnx', [Output('o', np.zeros((1, 8, 21), np.float32))], **kwargs
    )
    with pytest.raises(BackendError, match=message):
        load_model_spec(path)


def test_unknown_layouts_ask_for_the_model_family(tmp_path):
    path = write_model(tmp_path / 'm.onnx', [Output('o', np.zeros((1, 3, 4, 4), np.float32))])
    with pytest.raises(BackendError, match=r'o \[1, 3, 4, 4\]; pass --model-family'):
        load_model_spec(path)


def test_bad_files_and_families_are_reported(tmp_path):
    with pytest.raises(BackendError, match='model file not found'):
        load_model_spec(tmp_path / 'none.onnx')
    junk = tmp_path / 'junk.onnx'
    junk.write_bytes(b'not a model')
    with pytest.raises(BackendError, match='cannot load the ONNX model'):
        load_model_spec(junk)
    path = write_model(tmp_path / 'm.onnx', [Output('o', _v8_output())])
    with pytest.raises(BackendError, match="unknown model family 'ssd'"):
        load_model_spec(path, family='ssd')
    bad = write_model(
        tmp_path / 'b.onnx', [Output('o', _v8_output())], metadata={'replaybench.family': 'ssd'}
    )
    with pytest.raises(BackendError, match=r"metadata replaybench\.family='ssd'"):
        load_model_spec(bad)
    names = write_model(tmp_path / 'n.onnx', [Output('o', _v8_output())], metadata={'names': '{0:'})
    with pytest.raises(BackendError, match='model metadata "names"'):
        load_model_spec(names)
