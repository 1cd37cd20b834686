"""The stereo task end to end on the stereo fixture's bags: sgbm and bm replayed in pairs,
their DisparityImages in outputs.mcap, figures in summary.csv, frames.csv and run.json, the
gate on bad-2, the recorded backend on a DisparityImage topic, and bad pairs refused."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest

import replaybench as rb
from replaybench.decode import decode_image
from replaybench.fixtures.stereo import raw_camera_infos, write_stereo_mcap
from replaybench.fixtures.writer import FixtureMessage, write_ros2_mcap
from replaybench.msgs import typestore
from replaybench.sources import open_source
from replaybench.stereo import Matcher, score_disparity, stereo_pair
from replaybench.stereo.msgs import DISPARITY_IMAGE, serialize_disparity_image

if TYPE_CHECKING:
    from collections.abc import Iterator

    import numpy.typing as npt

FRAMES = 3
MOTORCYCLE = (
    Path(__file__).resolve().parents[2] / '..' / 'shared' / 'real' / 'stereo' / 'motorcycle'
)


@pytest.fixture(scope='module')
def bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    where = tmp_path_factory.mktemp('stereobags')
    return {
        'rect': write_stereo_mcap(where / 'stereo.mcap', FRAMES),
        'raw': write_stereo_mcap(where / 'stereo_raw.mcap', FRAMES, raw=True),
    }


@pytest.fixture(scope='module')
def both(bags: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('runs') / 'both'
    rb.run(bags['rect'], backends=['sgbm', 'bm'], out=out, sync='exact', report=False)
    return out


def _pairs(bag: Path) -> Iterator[tuple[Any, Any, npt.NDArray[np.float32]]]:
    """Each (left frame, right frame, truth) of a stereo fixture bag, in stamp order."""
    images: dict[tuple[str, int], Any] = {}
    with open_source(bag) as source:
        for raw in source.messages():
            if raw.msgtype == 'sensor_msgs/msg/Image':
                frame = decode_image(raw)
                images[(raw.topic.split('/')[-2], frame.stamp_ns)] = frame
    for (side, stamp), frame in sorted(images.items(), key=lambda kv: kv[0][1]):
        if side == 'left':
            yield frame, images[('right', stamp)], images[('ground_truth', stamp)].image


def _read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as f:
        return list(csv.DictReader(f))


def _disparity_messages(run: Path, topic: str) -> list[Any]:
    from mcap.reader import make_reader

    store = typestore(False)
    with (run / 'outputs.mcap').open('rb') as f:
        return [
            store.deserialize_cdr(message.data, DISPARITY_IMAGE)
            for _, channel, message in make_reader(f).iter_messages(topics=[topic])
        ]


def test_sgbm_replayed_gives_the_bare_matchers_disparity_bit_for_bit_and_its_pooled_figures(
    bags: dict[str, Path], both: Path
) -> None:
    matcher = Matcher('sgbm')
    bare, counts = [], []
    for left, right, truth in _pairs(bags['rect']):
        d = matcher.compute(left.image, right.image)
        bare.append(d)
        counts.append(score_disparity(d, truth))
    messages = _disparity_messages(both, '/replaybench/sgbm/stereo/left/image_rect/disparity')
    assert len(messages) == FRAMES
    for message, d in zip(messages, bare, strict=True):
        image = message.image
        assert (image.encoding, image.width, image.height) == ('32FC1', 320, 240)
        written = np.frombuffer(bytes(image.data), '<f4').reshape(240, 320)
        expected = np.where(np.isnan(d), np.float32(-1.0), d)  # no match: min_disparity - 1
        assert np.array_equal(written, expected)
        assert message.header.frame_id == 'stereo_left_optical_frame'
        assert (message.min_disparity, message.max_disparity, message.delta_d) == (0, 63, 1 / 16)
        assert message.t == pytest.approx(0.12)
        assert message.f > 0
        window = message.valid_window
        assert (window.x_offset, window.y_offset) == (70, 7)
    pooled = counts[0] + counts[1] + counts[2]
    row = next(r for r in _read_csv(both / 'summary.csv') if r['backend'] == 'sgbm')
    figures = pooled.figures()
    assert float(row['epe']) == pytest.approx(figures.epe, abs=1e-4)
    assert float(row['bad2']) == pytest.approx(figures.bad2, abs=1e-4)
    assert float(row['density']) == pytest.approx(figures.density, abs=1e-4)
    document = json.loads((both / 'run.json').read_text())
    metrics = next(r['task_metrics'] for r in document['summary'] if r['backend'] == 'sgbm')
    assert metrics['bad2'] == pytest.approx(figures.bad2)
    assert set(metrics) == {'epe', 'bad1', 'bad2', 'bad3', 'd1_all', 'density', 'abs_rel'} | {
        'streaming_epe',
        'streaming_bad2',
        'streaming_density',
    }
    frames = [r for r in _read_csv(both / 'frames.csv') if r['backend'] == 'sgbm']
    assert len(frames) == FRAMES
    for frame, c in zip(frames, counts, strict=True):
        assert float(frame['bad2']) == pytest.approx(c.figures().bad2, abs=1e-4)
    assert 0 < float(row['abs_rel']) < 0.1


def test_a_raw_pair_is_rectified_from_its_camera_info_as_the_bare_library_does(
    bags: dict[str, Path],
) -> None:
    run = rb.run(bags['raw'], backends=['sgbm'], sync='exact', report=False)
    (row,) = run.summary_rows
    rectifier, matcher, total = None, Matcher('sgbm'), None
    for left, right, truth in _pairs(bags['raw']):
        if rectifier is None:
            infos = raw_camera_infos((320, 240), left.stamp_ns)
            rectifier = stereo_pair(*infos).rectifier()
        d = matcher.compute(*rectifier.rectify(left.image, right.image))
        c = score_disparity(d, truth)
        total = c if total is None else total + c
    assert total is not None
    assert row.metric('bad2') == pytest.approx(total.figures().bad2)
    assert row.metric('epe') == pytest.approx(total.figures().epe)
    epe = row.metric('epe')
    assert epe is not None
    assert epe < 1.0  # unrectified, SGBM's EPE on this bag is about 11 px


def test_sgbm_with_float_maps_rectifies_with_them_and_says_so_and_a_bad_value_exits_2(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / 'float'
    done = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bags['raw']),
            '--backend',
            'sgbm',
            '--param',
            'sgbm.rectify_maps=float',
            '--out',
            str(out),
            '--no-report',
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    facts = json.loads((out / 'run.json').read_text(encoding='utf-8'))
    text = json.dumps(facts)
    assert '"rectify_maps": "float"' in text
    (row,) = _read_csv(out / 'summary.csv')
    rectifier, matcher, total = None, Matcher('sgbm'), None
    for left, right, truth in _pairs(bags['raw']):
        if rectifier is None:
            rectifier = stereo_pair(*raw_camera_infos((320, 240), left.stamp_ns)).rectifier('float')
        c = score_disparity(matcher.compute(*rectifier.rectify(left.image, right.image)), truth)
        total = c if total is None else total + c
    assert total is not None
    assert float(row['bad2']) == pytest.approx(total.figures().bad2, abs=1e-4)  # 4 places
    bad = subprocess.run(
        [
            sys.executable,
            '-m',
            'replaybench',
            'run',
            str(bags['raw']),
            '--backend',
            'sgbm',
            '--param',
            'sgbm.rectify_maps=half',
            '--out',
            str(tmp_path / 'bad'),
            '--no-report',
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert bad.returncode == 2
    lines = bad.stderr.strip().splitlines()
    assert len(lines) == 1, bad.stderr
    assert 'rectify_maps must be one of fixed, float' in lines[0]


def test_the_gate_fails_bm_against_sgbm_on_bad2(both: Path) -> None:
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'compare', str(both), '--baseline-backend', 'sgbm',
         '--fail-if', 'bad2 > +0.01'],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 1, done.stdout + done.stderr
    assert 'bad-2' in done.stdout + done.stderr


def test_without_sync_a_stereo_backend_pairs_by_equal_stamps_and_says_so(
    bags: dict[str, Path],
) -> None:
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'run', str(bags['rect']), '--backend', 'bm',
         '--no-report'],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert 'replaybench: --sync exact for bm (no --sync given)' in done.stderr


def _copy(
    bag: Path, out: Path, *, drop: str = '', extra: list[FixtureMessage] | None = None
) -> Path:
    from mcap.reader import make_reader

    kept = []
    with bag.open('rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic != drop:
                assert schema is not None
                kept.append(
                    FixtureMessage(message.log_time, channel.topic, schema.name, message.data)
                )
    kept += extra or []
    kept.sort(key=lambda m: m.log_time_ns)
    return write_ros2_mcap(out, kept)


def test_a_pair_without_the_right_camera_info_is_one_line_and_exit_2(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    bag = _copy(bags['rect'], tmp_path / 'noinfo.mcap', drop='/stereo/right/camera_info')
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'run', str(bag), '--backend', 'sgbm', '--sync',
         'exact', '--no-report'],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        'replaybench: error: sgbm: /stereo/left/image_rect, /stereo/right/image_rect: the right '
        'camera of the stereo pair has no CameraInfo'
    )


def test_the_recorded_backend_scores_a_recorded_disparity_image_topic(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    recorded = []
    for i, (left, _, truth) in enumerate(_pairs(bags['rect'])):
        values = truth.copy()
        if i == 0:
            values[:, :40] = np.nan  # no estimate there: bad pixels, less density
        data = serialize_disparity_image(
            left.stamp_ns,
            left.frame_id,
            values,
            f=100.0,
            t=0.12,
            min_disparity=0,
            max_disparity=63,
            delta_d=0.0,
        )
        recorded.append(
            FixtureMessage(left.log_time_ns + 5_000_000, '/ess/disparity', DISPARITY_IMAGE, data)
        )
    bag = _copy(bags['rect'], tmp_path / 'recorded.mcap', extra=recorded)
    run = rb.run(bag, backends=['recorded'], topics='/stereo/left/image_rect', report=False)
    (row,) = run.summary_rows
    assert row.metric('epe') == 0.0
    known = np.count_nonzero(np.isfinite(truth) & (truth != 0)) * FRAMES
    assert row.metric('density') == pytest.approx(1 - 40 * 240 / known, abs=1e-3)
    assert row.metric('bad2') == pytest.approx(40 * 240 / known, abs=1e-3)
    assert row.pipeline_ms_p50 == pytest.approx(5.0)


@pytest.mark.skipif(not MOTORCYCLE.is_dir(), reason='../shared/real/stereo/motorcycle absent')
def test_sgbm_replayed_on_middlebury_motorcycle_scores_as_the_bare_library_call(
    tmp_path: Path,
) -> None:
    import cv2

    from replaybench.msgs import CAMERA_INFO, IMAGE, serialize_camera_info, serialize_image
    from replaybench.types import CameraInfo

    left = np.asarray(cv2.imread(str(MOTORCYCLE / 'motorcycle_left.png')))
    right = np.asarray(cv2.imread(str(MOTORCYCLE / 'motorcycle_right.png')))
    truth = np.load(MOTORCYCLE / 'motorcycle_disp.npz')['arr_0'].astype(np.float32)
    h, w = left.shape[:2]
    stamp = 1_700_000_000_000_000_000
    f, cx, cy, b = 3979.911, 1244.772 / 4, 1019.507 / 4, 0.19343
    messages = []
    for side, image, tx in (('left', left, 0.0), ('right', right, -f * b)):
        info = CameraInfo(
            stamp,
            f'{side}_optical',
            w,
            h,
            'plumb_bob',
            (0.0,) * 5,
            (f, 0, cx, 0, f, cy, 0, 0, 1),
            (1, 0, 0, 0, 1, 0, 0, 0, 1),
            (f, 0, cx, tx, 0, f, cy, 0, 0, 0, 1, 0),
        )
        messages += [
            FixtureMessage(
                stamp, f'/mb/{side}/camera_info', CAMERA_INFO, serialize_camera_info(info)
            ),
            FixtureMessage(
                stamp,
                f'/mb/{side}/image_rect',
                IMAGE,
                serialize_image(stamp, info.frame_id, image, 'bgr8'),
            ),
        ]
    messages.append(
        FixtureMessage(
            stamp,
            '/ground_truth/disparity',
            IMAGE,
            serialize_image(stamp, 'left_optical', np.nan_to_num(truth, posinf=0.0), '32FC1'),
        )
    )
    bag = write_ros2_mcap(tmp_path / 'motorcycle.mcap', messages)
    run = rb.run(bag, backends=['sgbm'], sync='exact', report=False)
    (row,) = run.summary_rows
    from replaybench.stereo import to_mono8

    bare = Matcher('sgbm').compute(to_mono8(left, 'bgr8'), to_mono8(right, 'bgr8'))
    figures = score_disparity(bare, truth).figures()
    print(
        f'motorcycle sgbm replayed: EPE {row.metric("epe"):.3f} px, bad-2 {row.metric("bad2"):.4f}'
    )
    assert row.metric('epe') == pytest.approx(figures.epe)
    assert row.metric('bad2') == pytest.approx(figures.bad2)


def _renamed(bag: Path, names: dict[str, str]) -> list[FixtureMessage]:
    """The messages of ``bag``'s topics in ``names``, under their new names."""
    from mcap.reader import make_reader

    found = []
    with bag.open('rb') as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=list(names)):
            assert schema is not None
            found.append(
                FixtureMessage(message.log_time, names[channel.topic], schema.name, message.data)
            )
    return found


def test_a_stereo_backend_replays_the_pair_its_names_make_among_other_cameras(
    bags: dict[str, Path], both: Path, tmp_path: Path
) -> None:
    front = _renamed(bags['rect'], {'/stereo/left/image_rect': '/front/image_raw'})
    bag = _copy(bags['rect'], tmp_path / 'three.mcap', extra=front)
    out = tmp_path / 'run'
    rb.run(bag, backends=['sgbm'], out=out, report=False)
    document = json.loads((out / 'run.json').read_text())
    (row,) = (r for r in document['summary'] if r['backend'] == 'sgbm')
    (alone,) = (r for r in json.loads((both / 'run.json').read_text())['summary']
                if r['backend'] == 'sgbm')  # fmt: skip
    assert row['topic'] == '/stereo/left/image_rect'
    assert row['frames'] == FRAMES
    assert row['task_metrics'] == alone['task_metrics']
    assert [t['name'] for t in document['inputs'][0]['topics']] == [
        '/stereo/left/image_rect',
        '/stereo/right/image_rect',
    ]


def test_of_two_pairs_by_name_the_first_is_replayed_and_the_other_named(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    wide = _renamed(
        bags['rect'],
        {
            '/stereo/left/image_rect': '/wide/left/image_rect',
            '/stereo/right/image_rect': '/wide/right/image_rect',
            '/stereo/left/camera_info': '/wide/left/camera_info',
            '/stereo/right/camera_info': '/wide/right/camera_info',
        },
    )
    bag = _copy(bags['rect'], tmp_path / 'two.mcap', extra=wide)
    out = tmp_path / 'run'
    rb.run(bag, backends=['bm'], out=out, report=False)
    document = json.loads((out / 'run.json').read_text())
    replayed = [t['name'] for t in document['inputs'][0]['topics']]
    assert len(replayed) == 2
    other = next(ns for ns in ('/stereo', '/wide') if not replayed[0].startswith(ns))
    note = next(w for w in document['inputs'][0]['warnings'] if 'stereo pairs by name' in w)
    assert f'{other}/left/image_rect,{other}/right/image_rect' in note
    assert replayed[1] == replayed[0].replace('/left/', '/right/')


def test_with_depth_each_pair_also_has_a_32fc1_depth_image_in_metres_of_its_disparity(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    from mcap.reader import make_reader

    from replaybench.stereo.msgs import parse_disparity_image

    out = tmp_path / 'depth'
    rb.run(bags['rect'], backends=['sgbm'], out=out, report=False, depth=True)
    store = typestore(False)
    found: dict[str, dict[int, Any]] = {'disparity': {}, 'depth': {}}
    with (out / 'outputs.mcap').open('rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            kind = channel.topic.rsplit('/', 1)[-1]
            if channel.topic.startswith('/replaybench/sgbm/') and kind in found:
                assert schema is not None
                found[kind][message.log_time] = (schema.name, message.data)
    assert len(found['depth']) == FRAMES
    assert found['depth'].keys() == found['disparity'].keys()
    for log_time, (schema_name, data) in found['depth'].items():
        assert schema_name == 'sensor_msgs/msg/Image'
        image: Any = store.deserialize_cdr(data, 'sensor_msgs/msg/Image')
        assert image.encoding == '32FC1'
        depth = np.frombuffer(image.data, np.float32).reshape(image.height, image.width)
        disparity = parse_disparity_image(found['disparity'][log_time][1])
        estimated = disparity.disparity >= disparity.min_disparity
        with np.errstate(divide='ignore', invalid='ignore'):
            expected = np.where(
                estimated & (disparity.disparity > 0),
                disparity.f * disparity.t / disparity.disparity.astype(np.float64),
                np.nan,
            )
        assert image.header.stamp.sec * 10**9 + image.header.stamp.nanosec == disparity.stamp_ns
        np.testing.assert_allclose(depth, expected, rtol=1e-6, equal_nan=True)
        assert 0.1 < np.nanmedian(depth) < 10.0  # metres: a 0.12 m baseline at 256 px focal


def test_without_depth_no_depth_image_is_written(both: Path) -> None:
    from mcap.reader import make_reader

    with (both / 'outputs.mcap').open('rb') as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    topics = {c.topic for c in summary.channels.values()}
    assert not any(t.endswith('/depth') for t in topics)
    assert any(t.endswith('/disparity') for t in topics)


def _written(run: Path, backend: str) -> list[npt.NDArray[np.float32]]:
    """A backend's disparities as written in outputs.mcap, NaN where it has no estimate."""
    found = []
    for message in _disparity_messages(
        run, f'/replaybench/{backend}/stereo/left/image_rect/disparity'
    ):
        image = message.image
        d = np.frombuffer(bytes(image.data), '<f4').reshape(image.height, image.width)
        found.append(np.where(d >= message.min_disparity, d, np.nan).astype(np.float32))
    return found


def test_two_stereo_backends_agreement_is_the_seconds_disparity_against_the_firsts(
    both: Path, bags: dict[str, Path], tmp_path: Path
) -> None:
    document = json.loads((both / 'run.json').read_text())
    (row,) = document['stereo_agreement']
    assert (row['backend_a'], row['backend_b'], row['topic'], row['frames']) == (
        'sgbm',
        'bm',
        '/stereo/left/image_rect',
        FRAMES,
    )
    a, b = np.stack(_written(both, 'sgbm')), np.stack(_written(both, 'bm'))
    known = np.isfinite(a) & (a != 0)
    estimated = known & np.isfinite(b)
    error = np.abs(b - a)
    assert row['epe'] == pytest.approx(float(error[estimated].mean()), rel=1e-5)
    for n in (1, 2, 3):
        bad = known & ~(estimated & (error <= n))
        assert row[f'bad{n}'] == pytest.approx(bad.sum() / known.sum(), rel=1e-6)
    assert row['density'] == pytest.approx(estimated.sum() / known.sum(), rel=1e-6)
    assert 0 < row['bad2'] < 1
    loaded = rb.load_run(both)
    assert loaded.stereo_agreement is not None
    assert loaded.stereo_agreement[0].bad2 == row['bad2']
    one = tmp_path / 'one'
    rb.run(bags['rect'], backends=['sgbm'], out=one, report=False)
    assert 'stereo_agreement' not in json.loads((one / 'run.json').read_text())


def test_peak_finds_a_stereo_backends_rate_over_pairs_each_trial_scored(tmp_path: Path) -> None:
    bag = write_stereo_mcap(tmp_path / 'stereo.mcap', 8)
    out = tmp_path / 'peak'
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'peak', str(bag), '--backend', 'bm', '--out',
         str(out), '--max-hz', '400', '--refine-steps', '1', '--no-report'],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    document = json.loads((out / 'peak.json').read_text())
    assert document['peak_hz'] > 0
    assert document['trials']
    for trial in document['trials']:
        assert trial['frames'] == 8  # pairs: one row per frame set
        run = json.loads((out / trial['run_dir'] / 'run.json').read_text())
        (row,) = run['summary']
        assert row['topic'] == '/stereo/left/image_rect'
        assert row['task_metrics']['bad2'] is not None
