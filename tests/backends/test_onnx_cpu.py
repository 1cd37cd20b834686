"""The onnx-cpu backend: tiny ONNX graphs, the replay pipeline, and the real YOLOX-Nano."""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagtools import image_msg, write_mcap
from detector.onnxgraph import Output, write_model

from replaybench.backends import backend_table, get_backend
from replaybench.backends import onnx_cpu as onnx_cpu_module
from replaybench.backends.base import Backend, BackendOptions
from replaybench.backends.onnx_cpu import OnnxCpuBackend, session_options
from replaybench.decode import decode_detections
from replaybench.detector.spec import DEFAULT_MODEL
from replaybench.errors import BackendError
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.sinks.mcap_writer import detections_channel
from replaybench.sources import open_source
from replaybench.types import Detection, Frame

if TYPE_CHECKING:
    from collections.abc import Iterator
    from types import ModuleType

REAL = (Path(__file__).resolve().parents[2] / '..' / 'shared' / 'real').resolve()
YOLOX = REAL / 'models' / 'yolox_nano.onnx'
ASTRONAUT = REAL / 'images' / 'astronaut.png'
ARUCO_BAG = REAL / 'bags' / 'ros1' / 'ubiquity_aruco_images.bag'
#: Where check_model.py finds the astronaut (PROVENANCE.md).
ASTRONAUT_BOX = (11.0, 20.0, 369.0, 507.0)


def _frame(image: np.ndarray, encoding: str = 'bgr8', **kw: Any) -> Frame:
    return Frame('/camera/image', 0, 0, 0, 'camera', image, encoding, encoding, **kw)


def _v8_model(tmp_path: Path, **kw: Any) -> Path:
    """YOLOv8 layout on a 32x32 input, two classes, one box at model pixels (8, 12, 24, 20)."""
    out = np.zeros((1, 6, 21), np.float32)
    out[0, :, 5] = [16, 16, 16, 8, 0.9, 0.1]
    out[0, :, 6] = [17, 16, 16, 8, 0.8, 0.0]  # overlaps box 5, same class: suppressed
    out[0, :, 7] = [4, 4, 2, 2, 0.0, 0.2]  # below --conf
    metadata = {'names': 'ball,cup', **kw.pop('metadata', {})}
    return write_model(tmp_path / 'v8.onnx', [Output('output0', out)], metadata=metadata, **kw)


def _open(**kw: Any) -> OnnxCpuBackend:
    backend = OnnxCpuBackend(BackendOptions(**kw))
    backend.open()
    return backend


def _iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    inter = max(w, 0) * max(h, 0)
    area = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1])
    return inter / (area - inter)


def _box(det: Detection) -> tuple[float, float, float, float]:
    return (det.x0, det.y0, det.x1, det.y1)


def test_onnx_cpu_is_a_registered_available_backend():
    assert get_backend('onnx-cpu') is OnnxCpuBackend
    assert isinstance(OnnxCpuBackend(), Backend)
    row = {r.name: r for r in backend_table()}['onnx-cpu']
    assert row.availability.ok
    assert row.origin == 'built-in'


def test_without_a_model_the_missing_bundled_model_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setattr(onnx_cpu_module, 'DEFAULT_MODEL', tmp_path / 'blobs.onnx')
    backend = OnnxCpuBackend()
    with pytest.raises(BackendError, match=r'no --model given and the bundled model blobs\.onnx'):
        backend.open()
    with pytest.raises(BackendError, match=r'model file .*nothing\.onnx not found'):
        OnnxCpuBackend(BackendOptions(model=tmp_path / 'nothing.onnx')).open()


def test_the_bundled_model_opens_with_its_metadata():
    if not DEFAULT_MODEL.is_file():
        pytest.skip(f'{DEFAULT_MODEL} is not built yet')
    backend = _open()
    assert backend.spec is not None
    assert backend.spec.family == 'yolov8'
    assert backend.spec.class_names == ('red', 'green', 'blue', 'yellow')
    backend.close()


def test_a_yolov8_graph_gives_boxes_in_source_pixels(tmp_path):
    backend = _open(model=_v8_model(tmp_path), threads=1, conf=0.25)
    # 64x48 source into 32x32 centred: scale 0.5, 32x24, 4 rows of pad on top
    result = backend.detect(_frame(np.zeros((48, 64, 3), np.uint8)))
    dets = result.detections
    assert [(d.class_index, d.label, d.x0, d.y0, d.x1, d.y1) for d in dets] == [
        (0, 'ball', 16.0, 16.0, 48.0, 32.0)
    ]
    assert [d.score for d in dets] == pytest.approx([0.9])
    stages = result.stages
    assert all(isinstance(t, int) and t > 0 for t in stages[:3])
    assert stages.h2d_ns is None
    assert stages.d2h_ns is None
    again = backend.detect(_frame(np.zeros((48, 64, 3), np.uint8)))
    assert again.detections == result.detections
    backend.close()


def test_info_records_model_engine_and_threads(tmp_path):
    path = _v8_model(tmp_path)
    backend = _open(model=path, threads=2)
    info = backend.info()
    assert info['model'] == str(path)
    assert info['model_sha256'] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert info['family'] == 'yolov8'
    assert info['input_size'] == [32, 32]
    assert info['precision'] == 'fp32'
    assert info['num_classes'] == 2
    assert info['class_names'] == ['ball', 'cup']
    assert info['providers'] == ['CPUExecutionProvider']
    assert info['intra_op_threads'] == 2
    assert info['inter_op_threads'] == 1
    assert info['intra_op_spinning'] is False
    assert info['onnxruntime'] == __import__('onnxruntime').__version__
    assert (info['conf'], info['iou']) == (0.25, 0.45)
    backend.close()


def test_session_options_pin_threads_and_turn_spinning_off():
    so = session_options(3)
    assert (so.intra_op_num_threads, so.inter_op_num_threads) == (3, 1)
    assert so.get_session_config_entry('session.intra_op.allow_spinning') == '0'
    assert session_options(None).intra_op_num_threads == 0
    spinning = session_options(2, spinning=True)
    assert spinning.get_session_config_entry('session.intra_op.allow_spinning') == '1'


def test_conf_iou_and_labels_options_are_honoured(tmp_path):
    labels = tmp_path / 'labels.txt'
    labels.write_text('sun\nmoon\n', encoding='utf-8')
    backend = _open(model=_v8_model(tmp_path), conf=0.05, iou=0.99, labels=str(labels))
    dets = backend.detect(_frame(np.zeros((32, 32, 3), np.uint8))).detections
    assert [(d.label, round(d.score, 3)) for d in dets] == [
        ('sun', 0.9),
        ('sun', 0.8),
        ('moon', 0.2),
        ('moon', 0.1),
    ]


def test_an_nms_graph_with_separate_outputs_is_decoded(tmp_path):
    path = write_model(
        tmp_path / 'nms.onnx',
        [
            Output('num_dets', np.array([[2]], np.int32)),
            Output(
                'det_boxes', np.array([[[0, 0, 16, 16], [8, 8, 32, 32], [1, 1, 2, 2]]], np.float32)
            ),
            Output('det_scores', np.array([[0.9, 0.5, 0.95]], np.float32)),
            Output('det_classes', np.array([[2, 0, 1]], np.int32)),
        ],
    )
    backend = _open(model=path, labels='coco')
    # 64x64 source into 32x32: scale 0.5, no pad
    dets = backend.detect(_frame(np.zeros((64, 64, 3), np.uint8))).detections
    assert [(d.class_index, d.label, d.x0, d.y0, d.x1, d.y1) for d in dets] == [
        (2, 'car', 0.0, 0.0, 32.0, 32.0),
        (0, 'person', 16.0, 16.0, 64.0, 64.0),
    ]
    assert [d.score for d in dets] == pytest.approx([0.9, 0.5])
    assert backend.info()['nms'] == 'in graph'


def test_an_fp16_model_gets_a_float16_input(tmp_path):
    path = _v8_model(tmp_path, input_dtype=np.float16)
    backend = _open(model=path)
    assert backend.info()['precision'] == 'fp16'
    assert len(backend.detect(_frame(np.zeros((32, 32, 3), np.uint8))).detections) == 1


def test_mono_frames_are_accepted_and_depth_frames_refused(tmp_path):
    backend = _open(model=_v8_model(tmp_path))
    assert backend.detect(_frame(np.zeros((32, 32), np.uint8), 'mono8')).detections
    assert backend.detect(_frame(np.ones((32, 32), np.uint16), 'mono16')).detections
    depth = Frame('/depth', 3, 0, 0, 'c', np.ones((32, 32), np.uint16), 'mono16', '16UC1', True)
    with pytest.raises(BackendError, match=r'is a depth image \(16UC1\)'):
        backend.detect(depth)
    with pytest.raises(BackendError, match='depth image'):
        backend.detect(_frame(np.ones((32, 32), np.float32), '32FC1'))


@pytest.mark.parametrize(
    ('options', 'message'),
    [
        ({'conf': 1.5}, r'--conf must be within 0\.\.1'),
        ({'iou': -0.1}, r'--iou must be within 0\.\.1'),
        ({'model_family': 'ssd'}, "unknown --model-family 'ssd'"),
        ({'extra': {'colour': 'red'}}, "unknown option 'colour'"),
        ({'extra': {'max_det': '0'}}, 'max_det must be an integer >= 1'),
        ({'extra': {'allow_spinning': 'maybe'}}, 'allow_spinning must be 0 or 1'),
    ],
)
def test_bad_options_are_refused_when_the_backend_is_made(options, message):
    with pytest.raises(BackendError, match=message):
        OnnxCpuBackend(BackendOptions(**options))


def test_preprocessing_options_override_the_model_metadata(tmp_path):
    path = _v8_model(tmp_path, metadata={'replaybench.letterbox_align': 'center'})
    backend = _open(model=path, extra={'letterbox_align': 'topleft', 'pad_value': '0'})
    assert backend.info()['preprocess']['align'] == 'topleft'
    assert backend.info()['preprocess']['pad_value'] == 0
    # 64x48 source at the top-left: no vertical pad, box (8, 12, 24, 20) -> (16, 24, 48, 40)
    dets = backend.detect(_frame(np.zeros((48, 64, 3), np.uint8))).detections
    assert _box(dets[0]) == (16.0, 24.0, 48.0, 40.0)


def test_a_model_family_that_does_not_fit_the_outputs_is_reported_on_open(tmp_path):
    path = _v8_model(tmp_path)
    with pytest.raises(
        BackendError, match=r'onnx-cpu: .*v8\.onnx: yolox: output output0 has 6 rows'
    ):
        _open(model=path, model_family='yolox', labels='coco')
    with pytest.raises(BackendError, match='2 class names but the model outputs 16 classes'):
        _open(model=path, model_family='yolov5')


def _bag(path: Path, image_rgb: np.ndarray, frames: int = 1) -> Path:
    messages = [
        (
            '/camera/image',
            1_000 + i * 10**8,
            image_msg(1_000 + i * 10**8, image_rgb),
            'sensor_msgs/msg/Image',
        )
        for i in range(frames)
    ]
    write_mcap(path, messages)
    return path


def _written(run_dir: Path, topic: str = '/camera/image') -> list[tuple[Detection, ...]]:
    channel = detections_channel('onnx_cpu', topic)
    with open_source(run_dir / 'outputs.mcap') as source:
        return [decode_detections(raw).detections for raw in source.messages(topics=[channel])]


def test_a_replay_through_onnx_cpu_writes_its_detections(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', np.zeros((48, 64, 3), np.uint8), frames=3)
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['onnx-cpu'],
            out_dir=tmp_path / 'run',
            options=BackendOptions(model=_v8_model(tmp_path), threads=1),
            report=False,
        )
    )
    assert outcome.status == 'complete'
    assert outcome.run_dir is not None
    written = _written(outcome.run_dir)
    assert len(written) == 3
    for dets in written:
        assert [(d.label, _box(d)) for d in dets] == [('ball', (16.0, 16.0, 48.0, 32.0))]
    (backend,) = outcome.run.backends
    assert backend.name == 'onnx-cpu'
    assert backend.info['providers'] == ['CPUExecutionProvider']


# --- the real YOLOX-Nano ---------------------------------------------------------------------


@pytest.fixture(scope='module')
def real() -> Path:
    if not (YOLOX.is_file() and ASTRONAUT.is_file()):
        pytest.skip(f'{REAL} not present (real model and recordings are optional)')
    return REAL


@pytest.fixture(scope='module')
def check_model(real: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location('check_model', real / 'check_model.py')
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope='module')
def yolox(real: Path) -> Iterator[OnnxCpuBackend]:  # noqa: ARG001  ``real`` skips without the model
    backend = _open(model=YOLOX, labels='coco', threads=2)
    yield backend
    backend.close()


def test_yolox_nano_is_recognised_as_a_raw_grid_model(yolox):
    info = yolox.info()
    assert info['family'] == 'yolox'
    assert info['family_source'] == 'output shape + probe (raw grid)'
    assert info['input_size'] == [416, 416]
    assert info['conf'] == 0.3
    assert info['preprocess']['channel_order'] == 'bgr'
    assert info['preprocess']['align'] == 'topleft'
    assert info['preprocess']['scale'] == 1.0


@pytest.mark.usefixtures('real')
def test_yolox_nano_finds_the_astronaut_through_the_replay(tmp_path):
    bgr = cv2.imread(str(ASTRONAUT), cv2.IMREAD_COLOR)
    assert bgr is not None
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    bag = _bag(tmp_path / 'astronaut.mcap', rgb)
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['onnx-cpu'],
            out_dir=tmp_path / 'run',
            options=BackendOptions(model=YOLOX, labels='coco', threads=2),
            report=False,
        )
    )
    assert outcome.run_dir is not None
    (dets,) = _written(outcome.run_dir)
    people = [d for d in dets if d.label == 'person']
    assert len(people) == 1
    assert people[0].score >= 0.9
    assert _iou(_box(people[0]), ASTRONAUT_BOX) >= 0.9
    info = outcome.run.backends[0].info
    assert info['model_sha256'] == hashlib.sha256(YOLOX.read_bytes()).hexdigest()


def test_yolox_nano_agrees_with_check_model(yolox, check_model):
    image = cv2.imread(str(ASTRONAUT), cv2.IMREAD_COLOR)
    assert image is not None
    # a non-square crop too, so that letterbox padding is exercised
    for img in (image, np.ascontiguousarray(image[40:400, :])):
        ours = yolox.detect(_frame(img)).detections
        theirs = check_model.detect(yolox._session, img, 0.3, 0.45)
        assert len(ours) == len(theirs) >= 1
        for det, (score, cls, box) in zip(ours, theirs, strict=True):
            assert det.class_index == cls
            assert det.label == check_model.COCO_CLASSES[cls]
            assert det.score == pytest.approx(score, abs=1e-5)
            # check_model clips to width - 1; both map with the same scale
            np.testing.assert_allclose(_box(det), box, atol=1.01)


@pytest.mark.usefixtures('real')
def test_yolox_nano_finds_the_person_in_the_real_aruco_bag(tmp_path):
    if not ARUCO_BAG.is_file():
        pytest.skip(f'{ARUCO_BAG} not present')
    outcome = run_benchmark(
        RunConfig(
            inputs=[ARUCO_BAG],
            backends=['onnx-cpu'],
            out_dir=tmp_path / 'run',
            options=BackendOptions(model=YOLOX, labels='coco', threads=2),
            report=False,
        )
    )
    assert outcome.run_dir is not None
    (dets,) = _written(outcome.run_dir, '/raspicam_node/image/compressed')
    people = [d for d in dets if d.label == 'person']
    assert people, dets
    assert people[0].score == pytest.approx(0.68, abs=0.03)
    assert 0 <= people[0].x0 < people[0].x1 <= 1280
    assert 0 <= people[0].y0 < people[0].y1 <= 960
