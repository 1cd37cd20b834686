"""Models whose outputs hold NaN or inf: those candidates are left out and counted.

Real ONNX graphs (``onnxgraph.write_model``) run through onnxruntime: the CLI end to end, the
``onnx-cpu`` backend for every family, and the GPU pipeline's torch ops on the CPU against
the numpy decoders. Nothing non-finite may reach outputs.mcap, frames.csv or summary.csv.
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagtools import image_msg, write_mcap
from detector.onnxgraph import Output, write_model

from replaybench.backends.base import BackendOptions
from replaybench.backends.onnx_cpu import OnnxCpuBackend
from replaybench.decode import decode_detections
from replaybench.detector.decoders import NonfiniteTally, decode_nms, postprocess
from replaybench.detector.preprocess import Transform
from replaybench.detector.spec import ModelSpec, Preprocess
from replaybench.sinks.mcap_writer import detections_channel
from replaybench.sources import open_source
from replaybench.types import Detection, Frame

if TYPE_CHECKING:
    from collections.abc import Callable

REPO = Path(__file__).resolve().parents[2]
NAN, INF = np.nan, np.inf
LN2 = math.log(2.0)
NAMES = 'ball,cup'


def _v8_outputs() -> np.ndarray:
    """YOLOv8 ``[1, 6, 21]`` on 32x32: one good box, four with NaN / inf, one below conf."""
    out = np.zeros((1, 6, 21), np.float32)
    out[0, :, 5] = [16, 16, 16, 8, 0.9, 0.1]  # kept: model pixels (8, 12, 24, 20)
    out[0, :, 6] = [NAN, 16, 16, 8, 0.8, 0.0]  # NaN centre
    out[0, :, 7] = [4, 4, INF, 2, 0.7, 0.2]  # inf width
    out[0, :, 8] = [4, 4, 2, 2, NAN, 0.7]  # NaN class score
    out[0, :, 9] = [4, 4, 2, 2, INF, 0.1]  # inf class score
    out[0, :, 10] = [NAN, NAN, NAN, NAN, 0.0, 0.1]  # below conf: its box is not read
    return out


def _yolox_outputs() -> np.ndarray:
    """YOLOX ``[1, 21, 7]`` on 32x32 (strides 8, 16, 32: 16 + 4 + 1 rows)."""
    out = np.zeros((1, 21, 7), np.float32)
    out[0, 5] = [0.5, 0.5, 0.0, 0.0, 0.9, 0.1, 0.9]  # cell (1, 1): (8, 8, 16, 16), cup 0.81
    out[0, 0] = [0.5, 0.5, 100.0, 0.0, 0.9, 0.9, 0.0]  # exp(100) overflows float32
    out[0, 1] = [0.5, 0.5, 0.0, 0.0, NAN, 0.9, 0.0]  # NaN objectness
    out[0, 2] = [0.5, 0.5, 0.0, 0.0, 0.9, NAN, 0.5]  # NaN class score
    out[0, 3] = [0.5, 0.5, 0.0, 0.0, INF, 0.9, 0.0]  # inf objectness
    out[0, 4] = [0.5, 0.5, 0.0, 0.0, 0.1, NAN, NAN]  # objectness below conf: classes not read
    return out


def _v5_outputs() -> np.ndarray:
    """YOLOv5 ``[1, 6, 7]`` (cx, cy, w, h, obj, 2 classes)."""
    return np.array(
        [
            [
                [16, 16, 16, 8, 0.9, 0.9, 0.1],  # kept: (8, 12, 24, 20) ball
                [NAN, 16, 16, 8, 0.9, 0.9, 0.1],
                [16, 16, 16, -INF, 0.9, 0.9, 0.1],
                [16, 16, 16, 8, 0.9, 0.2, NAN],
                [16, 16, 16, 8, INF, 0.9, 0.1],
                [16, 16, 16, 8, 0.0, NAN, INF],  # objectness 0: classes not read
            ]
        ],
        np.float32,
    )


def _nms_outputs() -> np.ndarray:
    """NMS-in-graph ``[1, 6, 6]``: x0, y0, x1, y1, score, class."""
    return np.array(
        [
            [
                [8, 12, 24, 20, 0.9, 0],  # kept
                [NAN, 0, 16, 16, 0.8, 1],
                [0, 0, 16, 16, NAN, 1],
                [0, 0, INF, 16, 0.7, 0],
                [0, 0, 16, 16, 0.6, NAN],
                [NAN, NAN, NAN, NAN, 0.1, 0],  # score below conf: box not read
            ]
        ],
        np.float32,
    )


#: family -> (raw output, candidates with NaN / inf read per frame, kept (label, model box)).
FAMILIES: dict[str, tuple[Callable[[], np.ndarray], int, tuple[str, tuple[float, ...]]]] = {
    'yolov8': (_v8_outputs, 4, ('ball', (8.0, 12.0, 24.0, 20.0))),
    'yolox': (_yolox_outputs, 4, ('cup', (8.0, 8.0, 16.0, 16.0))),
    'yolov5': (_v5_outputs, 4, ('ball', (8.0, 12.0, 24.0, 20.0))),
    'nms': (_nms_outputs, 4, ('ball', (8.0, 12.0, 24.0, 20.0))),
}


def _model(tmp_path: Path, family: str) -> Path:
    make = FAMILIES[family][0]
    return write_model(
        tmp_path / f'{family}_nan.onnx',
        [Output('output0', make())],
        metadata={'names': NAMES},
    )


def _frame(seq: int = 0) -> Frame:
    return Frame('/camera/image', seq, 0, 0, 'cam', np.zeros((32, 32, 3), np.uint8), 'bgr8', 'bgr8')


def _finite_detection(det: Detection) -> bool:
    return all(math.isfinite(v) for v in (det.score, det.x0, det.y0, det.x1, det.y1))


# --- the decoders and the onnx-cpu backend ---------------------------------------------------


@pytest.mark.parametrize('family', list(FAMILIES))
def test_onnx_cpu_leaves_out_and_counts_candidates_with_nan_or_inf(tmp_path, family):
    _, bad, (label, box) = FAMILIES[family]
    backend = OnnxCpuBackend(
        BackendOptions(model=_model(tmp_path, family), model_family=family, conf=0.25, threads=1)
    )
    backend.open()
    try:
        for seq in range(3):
            dets = backend.detect(_frame(seq)).detections
            assert [(d.label, (d.x0, d.y0, d.x1, d.y1)) for d in dets] == [(label, box)]
            assert all(_finite_detection(d) for d in dets)
        info = backend.info()
    finally:
        backend.close()
    assert info['nonfinite_dropped'] == 3 * bad
    assert info['nonfinite_frames'] == 3


def test_a_model_with_finite_outputs_reports_nothing_left_out(tmp_path):
    out = _v8_outputs()
    out[0, :, 6:10] = 0.0
    path = write_model(tmp_path / 'ok.onnx', [Output('output0', out)], metadata={'names': NAMES})
    backend = OnnxCpuBackend(BackendOptions(model=path, model_family='yolov8', threads=1))
    backend.open()
    assert len(backend.detect(_frame()).detections) == 1
    assert backend.info()['nonfinite_dropped'] == 0
    assert backend.info()['nonfinite_frames'] == 0


def test_a_nan_detection_count_of_an_nms_graph_limits_nothing():
    outputs = {
        'num_dets': np.array([[NAN]], np.float32),
        'det_boxes': np.array([[[0, 0, 2, 2], [1, 1, 3, 3], [0, 0, 1, 1]]], np.float32),
        'det_scores': np.array([[0.9, INF, 0.4]], np.float32),
        'det_classes': np.array([[1, 0, 0]], np.int32),
    }
    boxes, scores, classes = decode_nms(outputs, conf=0.3)
    assert boxes.tolist() == [[0, 0, 2, 2], [0, 0, 1, 1]]
    assert scores.tolist() == pytest.approx([0.9, 0.4])
    assert classes.tolist() == [1, 0]


def test_the_tally_counts_frames_and_candidates_only_when_something_was_left_out():
    tally = NonfiniteTally()
    for dropped in (0, 3, 0, 1):
        tally.add(dropped)
    assert tally.info() == {'nonfinite_dropped': 4, 'nonfinite_frames': 2}


# --- the CLI, end to end ---------------------------------------------------------------------


def _bag(path: Path, frames: int) -> Path:
    pixels = np.zeros((48, 64, 3), np.uint8)
    write_mcap(
        path,
        [
            (
                '/camera/image',
                1_000 + i * 10**8,
                image_msg(1_000 + i * 10**8, pixels),
                'sensor_msgs/msg/Image',
            )
            for i in range(frames)
        ],
    )
    return path


def _numbers(path: Path) -> list[str]:
    with path.open(newline='') as handle:
        return [cell for row in csv.reader(handle) for cell in row]


def test_a_model_that_outputs_nan_and_inf_runs_to_the_end_through_the_cli(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', frames=3)
    out = tmp_path / 'run'
    result = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bag),
            '--backend',
            'onnx-cpu',
            '--model',
            str(_model(tmp_path, 'yolov8')),
            '--model-family',
            'yolov8',
            '--threads',
            '1',
            '--out',
            str(out),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
        timeout=300,
        check=False,
        cwd=REPO,
    )
    assert result.returncode == 0, result.stderr
    assert 'Traceback' not in result.stderr
    warning = (
        'replaybench: warning: onnx-cpu: left out 12 candidate(s) with NaN or inf model '
        'outputs in 3 frame(s)'
    )
    # besides the run's statistics warnings (3 measured frames: no interval)
    lines = [line for line in result.stderr.splitlines() if 'onnx_cpu /' not in line]
    assert lines == [warning]
    run = json.loads((out / 'run.json').read_text())
    (backend,) = run['backends']
    assert backend['info']['nonfinite_dropped'] == 12
    assert backend['info']['nonfinite_frames'] == 3
    assert run['status'] == 'complete'

    channel = detections_channel('onnx_cpu', '/camera/image')
    with open_source(out / 'outputs.mcap') as source:
        written = [decode_detections(raw).detections for raw in source.messages(topics=[channel])]
    assert len(written) == 3
    for dets in written:
        # 64x48 into 32x32: scale 0.5, 4 rows of padding on top
        assert [(d.label, (d.x0, d.y0, d.x1, d.y1)) for d in dets] == [
            ('ball', (16.0, 16.0, 48.0, 32.0))
        ]
        assert all(_finite_detection(d) for d in dets)

    for name in ('frames.csv', 'summary.csv'):
        cells = _numbers(out / name)
        assert not any(c.lower() in ('nan', 'inf', '-inf', '+inf') for c in cells), name
    with (out / 'frames.csv').open(newline='') as handle:
        assert [row['detections'] for row in csv.DictReader(handle)] == ['1', '1', '1']
    assert (out / 'report.html').is_file()


# --- the GPU pipeline's torch ops, on the CPU ------------------------------------------------


def _spec(family: str) -> ModelSpec:
    return ModelSpec(
        path=Path('m.onnx'),
        sha256='0' * 64,
        input_name='images',
        output_names=('output0',),
        family=family,
        preprocess=Preprocess(size=(32, 32)),
        class_names=('ball', 'cup'),
        precision='fp32',
    )


def _scatter(rng: np.random.Generator, raw: np.ndarray, share: float) -> np.ndarray:
    """``raw`` with a share of its values replaced by NaN, inf or -inf."""
    out = raw.copy()
    hit = rng.random(out.shape) < share
    out[hit] = rng.choice(np.array([NAN, INF, -INF], np.float32), size=int(hit.sum()))
    return out


def _dense(rng: np.random.Generator, family: str) -> np.ndarray:
    if family == 'yolov8':
        raw = rng.uniform(0, 1, (1, 6, 200)).astype(np.float32)
        raw[0, 0:4] *= 32
        return raw
    rows = 21 if family == 'yolox' else 200
    raw = rng.uniform(0, 1, (1, rows, 7)).astype(np.float32)
    if family == 'yolox':
        raw[0, :, 2:4] = rng.uniform(-1, 1, (rows, 2))
    else:
        raw[0, :, 0:4] *= 32
    return raw


@pytest.mark.parametrize('seed', range(4))
@pytest.mark.parametrize('family', ['yolox', 'yolov5', 'yolov8'])
def test_the_torch_pipeline_leaves_out_and_counts_what_the_numpy_one_does(family, seed):
    torch = pytest.importorskip('torch', reason='torch is not installed (CPU wheel is enough)')
    from replaybench.backends.gpu.cuda import DnnPipeline

    rng = np.random.default_rng(seed)
    raw = _scatter(rng, _dense(rng, family), 0.05)
    spec = _spec(family)
    transform = Transform(1.0, 0.0, 0.0, 32, 32)
    tally = NonfiniteTally()
    expected = postprocess({'output0': raw}, spec, transform, 0.3, 0.45, 300, tally)
    assert tally.dropped > 0

    pipeline = DnnPipeline(torch, spec, torch.device('cpu'), False, 0.3, 0.45, 300)
    arrays = pipeline.download(pipeline.postprocess({'output0': torch.from_numpy(raw)}, transform))
    got = pipeline.detections(arrays, transform)
    assert pipeline.nonfinite.info() == tally.info()
    assert [(d.label, d.class_index) for d in got] == [(d.label, d.class_index) for d in expected]
    for ours, theirs in zip(got, expected, strict=True):
        assert _finite_detection(ours)
        assert (ours.x0, ours.y0, ours.x1, ours.y1) == pytest.approx(
            (theirs.x0, theirs.y0, theirs.x1, theirs.y1), abs=1e-3
        )
        assert ours.score == pytest.approx(theirs.score, abs=1e-6)


def test_the_torch_pipeline_counts_an_nms_graph_through_the_numpy_decoder():
    torch = pytest.importorskip('torch', reason='torch is not installed (CPU wheel is enough)')
    from replaybench.backends.gpu.cuda import DnnPipeline

    spec = _spec('nms')
    transform = Transform(1.0, 0.0, 0.0, 32, 32)
    pipeline = DnnPipeline(torch, spec, torch.device('cpu'), False, 0.25, 0.45, 300)
    tensors = pipeline.postprocess({'output0': torch.from_numpy(_nms_outputs())}, transform)
    dets = pipeline.detections(pipeline.download(tensors), transform)
    assert [(d.label, d.x0, d.y0, d.x1, d.y1) for d in dets] == [('ball', 8, 12, 24, 20)]
    assert pipeline.nonfinite.info() == {'nonfinite_dropped': 4, 'nonfinite_frames': 1}
