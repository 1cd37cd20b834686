"""``replaybench quantize``: INT8 models calibrated on fixture bags through the backends' own
preprocessing, their provenance in the model and in ``run``, and the bad inputs it refuses.

The bundled models are quantised for real (ONNX Runtime's ``quantize_static``) on a few frames."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from typer.testing import CliRunner, Result

from replaybench.app.quantize import QuantizeSettings, head_nodes, quantize_model
from replaybench.backends.base import BackendOptions
from replaybench.backends.onnx_cpu import OnnxCpuBackend
from replaybench.backends.onnx_seg import OnnxSegBackend
from replaybench.cli import app
from replaybench.decode import decode_image
from replaybench.detector.calibration import calibration_frames
from replaybench.detector.provenance import PROVENANCE_KEY
from replaybench.sources import open_source

if TYPE_CHECKING:
    from replaybench.types import Frame

onnx = pytest.importorskip('onnx')
from onnx import TensorProto, helper  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / 'fixtures' / 'bags'
RAW = BAGS / 'rgb8_raw.mcap'
JPEG = BAGS / 'jpeg.mcap'
DETECTOR = REPO / 'replaybench' / 'models' / 'blobs.onnx'
SEGMENTER = REPO / 'replaybench' / 'models' / 'blobs_seg.onnx'
runner = CliRunner()


def _quantize(*args: str) -> Result:
    return runner.invoke(app, ['quantize', *args])


def _tiny_model(
    path: Path, *, dims: list[int | str] | None = None, opset: int = 17, domain: str = ''
) -> Path:
    """A 3x3 Conv then Relu on a [1, 3, 32, 32] input (``dims`` replaces the input shape)."""
    weight = helper.make_tensor(
        'w', TensorProto.FLOAT, [4, 3, 3, 3], np.linspace(-1, 1, 108, dtype=np.float32)
    )
    shape = dims if dims is not None else [1, 3, 32, 32]
    nodes = [
        helper.make_node('Conv', ['images', 'w'], ['c'], name='conv', pads=[1, 1, 1, 1]),
        helper.make_node('Relu', ['c'], ['out'], name='relu', domain=domain),
    ]
    graph = helper.make_graph(
        nodes,
        'tiny',
        [helper.make_tensor_value_info('images', TensorProto.FLOAT, shape)],
        [helper.make_tensor_value_info('out', TensorProto.FLOAT, None)],
        [weight],
    )
    imports = [helper.make_opsetid('', opset)]
    if domain:
        imports.append(helper.make_opsetid(domain, 1))
    model = helper.make_model(graph, opset_imports=imports)
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


def _frames(bag: Path) -> list[Frame]:
    with open_source(bag) as source:
        topic = next(t.name for t in source.topics() if t.msgtype.endswith('Image'))
        frames = [decode_image(m) for m in source.messages(topics=[topic])]
        return [f._replace(image=np.array(f.image)) for f in frames]


# -- the bundled detector ----------------------------------------------------------------------


@pytest.fixture(scope='module')
def int8_detector(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp('int8')
    model = folder / 'blobs.onnx'
    shutil.copyfile(DETECTOR, model)
    out: Path = folder / 'blobs.int8.onnx'
    result = _quantize(str(model), str(RAW), '--out', str(out), '--frames', '10')
    assert result.exit_code == 0, result.output
    return out


def test_quantize_writes_only_its_out_never_beside_the_input_model(int8_detector) -> None:
    # quantize_static alone would leave blobs-inferred.onnx beside blobs.onnx
    assert sorted(p.name for p in int8_detector.parent.iterdir()) == [
        'blobs.int8.onnx',
        'blobs.onnx',
    ]


def test_the_int8_model_holds_quantize_nodes_and_keeps_the_decode_head_in_float(
    int8_detector,
) -> None:
    model = onnx.load(str(int8_detector))
    ops = [n.op_type for n in model.graph.node]
    assert ops.count('QuantizeLinear') > 5
    assert ops.count('DequantizeLinear') > 5
    float_model = onnx.load(str(DETECTOR))
    head = head_nodes(float_model)
    assert '/inner/out/Conv' in head
    assert '/Sigmoid' in head
    by_name = {n.name: n for n in model.graph.node}
    # the head's Conv still takes a float weight (no DequantizeLinear in front of it)
    producers = {o: n for n in model.graph.node for o in n.output}
    weight = by_name['/inner/out/Conv'].input[1]
    assert weight not in producers or producers[weight].op_type != 'DequantizeLinear'


def test_the_provenance_names_the_bag_its_sha256_the_frames_method_and_excluded_nodes(
    int8_detector,
) -> None:
    import hashlib

    model = onnx.load(str(int8_detector))
    meta = {p.key: p.value for p in model.metadata_props}
    record = json.loads(meta[PROVENANCE_KEY])
    assert record['bag'] == 'rgb8_raw.mcap'
    assert record['bag_sha256'] == hashlib.sha256(RAW.read_bytes()).hexdigest()
    assert record['topics'] == ['/camera/image_raw']
    assert record['frames'] == 10
    assert record['frames_used'] == {'/camera/image_raw': list(range(10))}
    assert record['method'] == 'minmax'
    assert record['excluded'] == list(head_nodes(onnx.load(str(DETECTOR))))
    assert record['source_sha256'] == hashlib.sha256(DETECTOR.read_bytes()).hexdigest()
    from replaybench import __version__

    assert record['replaybench'] == __version__
    # the float model's own metadata is kept: onnx-cpu still reads its family and classes
    assert meta['replaybench.family'] == 'yolov8'
    assert meta['names'] == 'red,green,blue,yellow'


def test_the_int8_detector_loses_at_most_0_02_map50_on_held_out_fixture_frames(
    int8_detector, tmp_path
) -> None:
    # calibrated on rgb8_raw.mcap; scored on the other fixture bags' frames
    scores = {}
    for name, model in (('fp32', DETECTOR), ('int8', int8_detector)):
        out = tmp_path / name
        args = ['run', str(JPEG), str(BAGS / 'two_camera.mcap'), '-b', 'onnx-cpu']
        args += ['--model', str(model), '--out', str(out), '--no-report', '--no-hash']
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        run = json.loads((out / 'run.json').read_text(encoding='utf-8'))
        (backend,) = run['backends']
        scores[name] = backend
        rows = [
            line.split(',')
            for line in (out / 'summary.csv').read_text(encoding='utf-8').splitlines()
        ]
        header = rows[0]
        maps = [float(r[header.index('map50')]) for r in rows[1:] if r[header.index('map50')]]
        scores[name] = sum(maps) / len(maps)
        if name == 'int8':
            assert run['backends'][0]['info']['quantization']['bag'] == 'rgb8_raw.mcap'
            assert 'onnx-cpu: INT8 model calibrated by replaybench' in result.stdout
            assert 'rgb8_raw.mcap' in result.stdout
        else:
            assert run['backends'][0]['info']['quantization'] is None
            assert 'INT8' not in result.stdout
    assert scores['fp32'] > 0.8
    assert scores['fp32'] - scores['int8'] <= 0.02, scores


def test_exclude_none_quantises_the_head_too_and_says_so_in_the_metadata(tmp_path) -> None:
    out = tmp_path / 'all.onnx'
    result = _quantize(
        str(DETECTOR), str(RAW), '--out', str(out), '--frames', '3', '--exclude', 'none'
    )
    assert result.exit_code == 0, result.output
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    record = json.loads(meta[PROVENANCE_KEY])
    assert record['excluded'] == []
    assert record['exclude_rule'] == 'none'
    assert record['frames'] == 3
    assert '0 node(s) in float' in result.stdout


def test_exclude_names_nodes_and_refuses_a_node_the_model_lacks(tmp_path) -> None:
    out = tmp_path / 'some.onnx'
    result = _quantize(
        str(DETECTOR), str(RAW), '--out', str(out), '--frames', '2', '--exclude', '/Sigmoid'
    )
    assert result.exit_code == 0, result.output
    record = json.loads(
        {p.key: p.value for p in onnx.load(str(out)).metadata_props}[PROVENANCE_KEY]
    )
    assert record['excluded'] == ['/Sigmoid']
    bad = _quantize(
        str(DETECTOR), str(RAW), '--out', str(tmp_path / 'x.onnx'), '--exclude', 'no-such'
    )
    assert bad.exit_code == 2
    assert bad.stderr.strip().splitlines() == [
        "replaybench: error: --exclude 'no-such': the model has no node of that name"
    ]


def test_the_calibration_sees_what_onnx_cpu_feeds_its_session() -> None:
    frame = _frames(RAW)[3]
    backend = OnnxCpuBackend(BackendOptions(model=DETECTOR))
    backend.open()
    try:
        feed = backend.inputs(frame)
        backend.detect(frame)
        assert set(feed) == {'images'}
        np.testing.assert_array_equal(feed['images'], backend._feed['images'])
        assert feed['images'] is not backend._feed['images']
    finally:
        backend.close()


# -- frames: spread evenly, never held out -----------------------------------------------------


def test_calibration_frames_are_spread_evenly_over_the_bag() -> None:
    picked = calibration_frames(RAW, 4)
    assert [f.seq for f in picked.frames] == [0, 3, 6, 9]
    assert picked.available == 10
    assert picked.topics == ('/camera/image_raw',)


def test_frames_held_out_are_never_calibrated_on() -> None:
    # frame i is logged at i/30 s: --holdout 0.15: keeps frames 0..4 only
    picked = calibration_frames(RAW, 3, holdout=[(0.15, None)])
    assert [f.seq for f in picked.frames] == [0, 2, 4]
    assert picked.available == 5
    middle = calibration_frames(RAW, 10, holdout=[(0.1, 0.2)])
    assert [f.seq for f in middle.frames] == [0, 1, 2, 6, 7, 8, 9]


def test_a_bag_with_fewer_frames_than_asked_uses_them_all_and_says_so_once(tmp_path) -> None:
    out = tmp_path / 'm.onnx'
    result = _quantize(str(DETECTOR), str(RAW), '--out', str(out), '--frames', '50')
    assert result.exit_code == 0, result.output
    warnings = [ln for ln in result.stderr.splitlines() if 'warning' in ln]
    assert warnings == [
        (
            'replaybench: warning: rgb8_raw.mcap holds 10 frame(s) to calibrate on, fewer than '
            '--frames 50: all 10 used'
        )
    ]
    record = json.loads(
        {p.key: p.value for p in onnx.load(str(out)).metadata_props}[PROVENANCE_KEY]
    )
    assert record['frames'] == 10
    assert record['frames_asked'] == 50


def test_a_holdout_that_leaves_no_frame_is_one_line(tmp_path) -> None:
    result = _quantize(
        str(DETECTOR), str(RAW), '--out', str(tmp_path / 'm.onnx'), '--holdout', '0:'
    )
    assert result.exit_code == 2
    assert len(result.stderr.strip().splitlines()) == 1
    assert 'no frame left to calibrate on' in result.stderr
    assert not (tmp_path / 'm.onnx').exists()


@pytest.mark.parametrize('text', ['5', 'a:b', '3:1', '-1:'])
def test_a_malformed_holdout_is_one_line_exit_2(tmp_path, text) -> None:
    result = _quantize(
        str(DETECTOR), str(RAW), '--out', str(tmp_path / 'm.onnx'), '--holdout', text
    )
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines()[-1].startswith('replaybench: error: --holdout')


# -- segmentation ------------------------------------------------------------------------------


def test_the_bundled_segmenter_quantises_through_onnx_seg_and_its_masks_agree(tmp_path) -> None:
    out = tmp_path / 'seg.int8.onnx'
    result = _quantize(str(SEGMENTER), str(RAW), '--out', str(out), '--frames', '5')
    assert result.exit_code == 0, result.output
    assert 'through onnx-seg' in result.stdout
    frames = _frames(JPEG)
    masks = {}
    for name, model in (('fp32', SEGMENTER), ('int8', out)):
        backend = OnnxSegBackend(BackendOptions(model=model, threads=1))
        backend.open()
        try:
            found = [backend.detect(f).mask for f in frames]
            masks[name] = [m.labels for m in found if m is not None]
            info = backend.info()
        finally:
            backend.close()
        assert (info['quantization'] is None) == (name == 'fp32')
    agree = np.mean([np.mean(a == b) for a, b in zip(masks['fp32'], masks['int8'], strict=True)])
    assert agree >= 0.98, agree
    assert not all(np.array_equal(a, b) for a, b in zip(masks['fp32'], masks['int8'], strict=True))


# -- opset and bad models ----------------------------------------------------------------------


def test_an_opset_11_model_is_upgraded_to_13_and_recorded(tmp_path) -> None:
    model = _tiny_model(tmp_path / 'old.onnx', opset=11)
    out = tmp_path / 'old.int8.onnx'
    args = [str(model), str(RAW), '--out', str(out), '--frames', '2', '--backend', 'onnx-seg']
    result = _quantize(*args)
    assert result.exit_code == 0, result.output
    assert 'opset 11 -> 13' in result.stdout
    written = onnx.load(str(out))
    assert max(o.version for o in written.opset_import if o.domain in ('', 'ai.onnx')) >= 13
    record = json.loads({p.key: p.value for p in written.metadata_props}[PROVENANCE_KEY])
    assert (record['opset_from'], record['opset_to']) == (11, 13)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['old.int8.onnx', 'old.onnx']


def _one_error(result: Result) -> str:
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert 'Traceback' not in result.output
    return lines[0]


def test_a_model_with_no_static_input_size_is_one_line(tmp_path) -> None:
    model = _tiny_model(tmp_path / 'dyn.onnx', dims=[1, 3, 'height', 'width'])
    line = _one_error(_quantize(str(model), str(RAW), '--out', str(tmp_path / 'o.onnx')))
    assert "input 'images' has no static size" in line


def test_an_opset_too_old_to_upgrade_is_one_line(tmp_path) -> None:
    model = _tiny_model(tmp_path / 'ancient.onnx', opset=6)
    line = _one_error(_quantize(str(model), str(RAW), '--out', str(tmp_path / 'o.onnx')))
    assert 'opset 6 is too old to upgrade to 13' in line


def test_an_unsupported_op_is_one_line(tmp_path) -> None:
    model = _tiny_model(tmp_path / 'custom.onnx', domain='com.example')
    line = _one_error(_quantize(str(model), str(RAW), '--out', str(tmp_path / 'o.onnx')))
    assert 'unsupported op com.example.Relu' in line


def test_a_file_that_is_no_onnx_model_is_one_line(tmp_path) -> None:
    model = tmp_path / 'text.onnx'
    model.write_bytes(b'\xff\xfe not a model at all')
    line = _one_error(_quantize(str(model), str(RAW), '--out', str(tmp_path / 'o.onnx')))
    assert 'not an ONNX model' in line


def test_a_corrupt_or_non_onnx_out_target_is_refused_and_left_as_it_was(tmp_path) -> None:
    out = tmp_path / 'notes.onnx'
    out.write_bytes(b'\xff\xfe my notes')
    line = _one_error(_quantize(str(DETECTOR), str(RAW), '--out', str(out), '--frames', '1'))
    assert 'is not an ONNX model' in line
    assert out.read_bytes() == b'\xff\xfe my notes'
    folder = tmp_path / 'folder.onnx'
    folder.mkdir()
    assert 'not a file' in _one_error(_quantize(str(DETECTOR), str(RAW), '--out', str(folder)))
    same = _one_error(_quantize(str(DETECTOR), str(RAW), '--out', str(DETECTOR)))
    assert 'is the input model' in same


def test_an_existing_onnx_out_is_replaced(tmp_path) -> None:
    out = tmp_path / 'again.onnx'
    shutil.copyfile(SEGMENTER, out)
    result = _quantize(str(DETECTOR), str(RAW), '--out', str(out), '--frames', '1')
    assert result.exit_code == 0, result.output
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert meta['replaybench.family'] == 'yolov8'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['again.onnx']


def test_an_unknown_method_is_one_line(tmp_path) -> None:
    line = _one_error(
        _quantize(str(DETECTOR), str(RAW), '--out', str(tmp_path / 'o.onnx'), '--method', 'kl')
    )
    assert "--method 'kl'" in line


@pytest.mark.parametrize('method', ['entropy', 'percentile'])
def test_entropy_and_percentile_calibrate_too_and_print_nothing(tmp_path, method, capfd) -> None:
    out = tmp_path / f'{method}.onnx'
    settings = QuantizeSettings(model=SEGMENTER, bag=RAW, out=out, frames=2, method=method)
    outcome = quantize_model(settings)
    assert outcome.provenance['method'] == method
    assert out.is_file()
    printed = capfd.readouterr()
    assert printed.out == ''
    assert printed.err == ''


def test_ground_truth_mask_topics_are_never_calibrated_on(tmp_path) -> None:
    from replaybench.fixtures.writer import write_mcap

    bag = write_mcap(tmp_path / 'masks.mcap', 4, masks=True)
    picked = calibration_frames(bag, 8)
    assert picked.topics == ('/camera/image_raw',)
    assert {f.topic for f in picked.frames} == {'/camera/image_raw'}


def test_the_bundled_stereo_model_calibrates_on_pairs_through_onnx_stereo(tmp_path) -> None:
    from replaybench.fixtures.stereo import write_stereo_mcap

    bag = write_stereo_mcap(tmp_path / 'stereo.mcap', frames=4, size=(320, 240))
    left, right = '/stereo/left/image_rect', '/stereo/right/image_rect'
    stereo_model = REPO / 'replaybench' / 'models' / 'stereo_small.onnx'
    out = tmp_path / 'stereo.int8.onnx'
    args = [str(stereo_model), str(bag), '--out', str(out), '--frames', '3']
    result = _quantize(*args, '--topic', left, '--topic', right)
    assert result.exit_code == 0, result.output
    assert 'through onnx-stereo' in result.stdout
    record = json.loads(
        {p.key: p.value for p in onnx.load(str(out)).metadata_props}[PROVENANCE_KEY]
    )
    assert record['backend'] == 'onnx-stereo'
    assert record['frames'] == 3
    assert record['frames_used'] == {left: [0, 2, 3], right: [0, 2, 3]}
    one = _one_error(_quantize(*args, '--topic', left))
    assert 'two topics: --topic LEFT --topic RIGHT' in one


def test_bundled_names_the_backends_default_model_and_out_folders_are_made(tmp_path) -> None:
    out = tmp_path / 'new' / 'folder' / 'm.onnx'
    result = _quantize('bundled', str(RAW), '--out', str(out), '--frames', '4')
    assert result.exit_code == 0, result.stderr
    record = json.loads(
        {p.key: p.value for p in onnx.load(str(out)).metadata_props}['replaybench.quantization']
    )
    digest = hashlib.sha256(DETECTOR.read_bytes()).hexdigest()
    assert record['source_sha256'] == digest
    assert record['source'] == 'blobs.onnx'
    refused = _quantize('bundled', str(RAW), '--out', str(tmp_path / 'x.onnx'), '-b', 'hsv')
    assert refused.exit_code == 2
    assert refused.stderr.strip().splitlines()[-1] == (
        'replaybench: error: no bundled model for --backend hsv: give onnx-cpu, onnx-seg or '
        'onnx-stereo'
    )
