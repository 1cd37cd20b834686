"""What the precision costs: two backends over the same frames compared frame by frame — the
mAP@0.5 change with a bootstrap interval paired by frame, the agreement of their boxes, and the
frames where they agree least (real runs of the fixture bag, read back from their folders)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

import replaybench as rb
from replaybench.comparison.core import compare_runs
from replaybench.comparison.output import CSV_COLUMNS, PAIRED_COLUMNS
from replaybench.comparison.paired import PAIRED_RESAMPLES, box_agreement
from replaybench.results.accuracy import evaluate
from replaybench.sinks.mcap_writer import detections_channel
from replaybench.sources import open_source
from replaybench.tasks.detections.truth import read_detections
from replaybench.types import Detection

if TYPE_CHECKING:
    from replaybench.results.model import Comparison, ComparisonRow

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
TOPIC = '/camera/image_raw'
CHROMIUM_PATH = '/usr/bin/chromium'


@pytest.fixture(scope='module')
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``two``: hsv and onnx-cpu in one run; ``hsv``: hsv alone, another run of the same bag."""
    base = tmp_path_factory.mktemp('paired')
    two, alone = base / 'two', base / 'hsv'
    rb.run(RAW, backends=['hsv', 'onnx-cpu'], out=two)
    rb.run(RAW, backends='hsv', out=alone)
    return {'two': two, 'hsv': alone}


def _row(comparison: Comparison, backend: str) -> ComparisonRow:
    return next(r for r in comparison.rows if r.role == 'candidate' and r.backend == backend)


@pytest.fixture(scope='module')
def compared(runs: dict[str, Path]) -> Comparison:
    """The run of two backends compared as the API compares it (onnx-cpu against hsv)."""
    return rb.compare(runs['two'], baseline_backend='hsv')


def test_two_backends_of_one_run_get_the_change_and_the_interval_of_a_direct_paired_bootstrap(
    runs: dict[str, Path], compared: Comparison
) -> None:
    assert _row(compared, 'onnx_cpu').paired.resamples == PAIRED_RESAMPLES  # type: ignore[union-attr]
    # fewer draws than the default keep the direct computation below quick
    resamples = 200
    comparison = compare_runs([runs['two']], baseline_backend='hsv', paired_resamples=resamples)
    row = next(r for r in comparison.rows if r.backend == 'onnx_cpu')
    paired = row.paired
    assert paired is not None
    # the independent computation: boxes and truth read back, resampled by numpy, scored by
    # evaluate on each draw (each drawn frame a frame of its own)
    with open_source(runs['two'] / 'outputs.mcap') as source:
        hsv = read_detections(source, detections_channel('hsv', TOPIC))
        onnx = read_detections(source, detections_channel('onnx_cpu', TOPIC))
    with open_source(RAW) as source:
        truth = read_detections(source, '/ground_truth/detections')
    keys = sorted(truth)
    n = len(keys)
    draws = np.random.default_rng(0).integers(0, n, size=(resamples, n))

    def map50(dets: dict[tuple[str, int], tuple[Detection, ...]], picks: list[int]) -> float:
        gt = {i: truth[keys[j]] for i, j in enumerate(picks)}
        return evaluate(gt, {i: dets[keys[j]] for i, j in enumerate(picks)}).map50

    changes = [map50(onnx, p) - map50(hsv, p) for p in draws.tolist()]
    lo, hi = np.quantile(changes, [0.025, 0.975])
    assert paired.frames == n == 10
    assert paired.resamples == resamples
    assert paired.seed == 0
    assert paired.confidence == 0.95
    assert paired.ci is not None
    assert paired.ci[0] == pytest.approx(lo, abs=1e-12)
    assert paired.ci[1] == pytest.approx(hi, abs=1e-12)
    # the point change is the run's own: run.json's mAP@0.5 of each backend
    assert paired.ci != _row(compared, 'onnx_cpu').paired.ci  # type: ignore[union-attr]
    run = rb.load_run(runs['two'])
    by_backend = {s.backend: s.map50 for s in run.summary_rows if s.topic == TOPIC}
    assert paired.baseline == pytest.approx(by_backend['hsv'], abs=1e-12)
    assert paired.candidate == pytest.approx(by_backend['onnx_cpu'], abs=1e-12)
    assert row.metrics['map50'].diff == pytest.approx(paired.change, abs=1e-12)
    assert row.metrics['map50'].diff_ci == paired.ci
    assert row.metrics['map50'].method == 'paired-bootstrap'
    assert paired.change is not None
    assert paired.ci[0] < paired.change < paired.ci[1]
    # the two detectors differ on some frames: agreement below 1, the worst frames listed
    assert paired.matched_mean is not None
    assert 0.5 < paired.matched_mean < 1.0
    assert paired.worst
    assert [f.matched for f in paired.worst] == sorted(f.matched for f in paired.worst)
    # the latency ratio is still the one compare makes
    assert row.metrics['median_ms'].ratio is not None


def test_the_same_backend_over_the_same_frames_changes_nothing_and_agrees_fully(
    runs: dict[str, Path],
) -> None:
    comparison = rb.compare(runs['two'], runs['hsv'])
    paired = _row(comparison, 'hsv').paired
    assert paired is not None
    assert paired.change == 0.0
    assert paired.ci == (0.0, 0.0)
    assert paired.matched_mean == paired.iou_mean == paired.matched_min == 1.0
    assert paired.agreeing_frames == paired.frames == 10
    assert paired.worst == ()


def test_agreement_of_a_frame_counts_matched_boxes_and_best_ious_of_both_sides() -> None:
    a = (Detection(0, 'red', 0.9, 0, 0, 10, 10), Detection(1, 'blue', 0.8, 20, 20, 30, 30))
    b = (Detection(0, 'red', 0.7, 0, 0, 10, 5), Detection(0, 'red', 0.6, 50, 50, 60, 60))
    found = box_agreement(a, b)
    # red matches red at IoU 0.5 (one pair); blue and the second red find nothing
    assert found.matched == pytest.approx(2 * 1 / 4)
    assert found.iou == pytest.approx((0.5 + 0.0 + 0.5 + 0.0) / 4)
    assert box_agreement((), ()).matched == 1.0


def test_the_map50_gate_judges_the_point_estimate_and_names_the_paired_interval(
    runs: dict[str, Path], compared: Comparison
) -> None:
    def gate(condition: str) -> subprocess.CompletedProcess[str]:
        command = ['compare', str(runs['two']), '--baseline-backend', 'hsv', '--fail-if']
        return subprocess.run(
            [sys.executable, '-m', 'replaybench', *command, condition],
            capture_output=True,
            text=True,
            check=False,
        )

    change = _row(compared, 'onnx_cpu').paired.change  # type: ignore[union-attr]
    assert change is not None
    assert change < -0.01
    failed = gate('map50 < -0.01')
    assert failed.returncode == 1, failed.stderr
    assert 'FAIL map50 < -0.01' in failed.stderr
    assert '95% CI' in failed.stderr
    assert 'judged on the point estimate' in failed.stderr
    assert 'paired bootstrap' in failed.stdout
    passed = gate(f'map50 < {change - 0.01:+.4f}')
    assert passed.returncode == 0, passed.stderr


def test_every_output_carries_the_paired_figures_and_the_page_shows_the_least_agreeing_frames(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / 'cmp'
    comparison = rb.compare(
        runs['two'], baseline_backend='hsv', out=out, markdown=tmp_path / 'c.md'
    )
    paired = _row(comparison, 'onnx_cpu').paired
    assert paired is not None
    assert paired.ci is not None
    lines = (out / 'comparison.csv').read_text().splitlines()
    header = lines[0].split(',')
    assert tuple(header) == CSV_COLUMNS
    assert header[-len(PAIRED_COLUMNS) :] == list(PAIRED_COLUMNS)
    import csv

    with (out / 'comparison.csv').open(newline='') as f:
        rows = {r['backend']: r for r in csv.DictReader(f)}
    assert float(rows['onnx_cpu']['paired_ci_low']) == pytest.approx(paired.ci[0], abs=1e-5)
    assert rows['onnx_cpu']['paired_resamples'] == str(PAIRED_RESAMPLES)
    assert rows['onnx_cpu']['paired_metric'] == 'map50'
    assert rows['hsv']['paired_frames'] == ''  # the baseline row is not paired
    document = json.loads((out / 'comparison.json').read_text())
    row = next(r for r in document['rows'] if r['backend'] == 'onnx_cpu')
    assert row['paired']['ci'] == list(paired.ci)
    assert len(row['paired']['worst']) == len(paired.worst)
    assert 'paired' not in next(r for r in document['rows'] if r['backend'] == 'hsv')
    assert 'paired' in (tmp_path / 'c.md').read_text()
    if not Path(CHROMIUM_PATH).is_file():
        pytest.skip(f'{CHROMIUM_PATH} is missing (apt-get install -y chromium)')
    playwright = pytest.importorskip('playwright.sync_api')
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=CHROMIUM_PATH, args=['--no-sandbox', '--disable-gpu'], headless=True
        )
        try:
            page = browser.new_page(viewport={'width': 1366, 'height': 900})
            requests: list[str] = []
            page.on('request', lambda r: requests.append(r.url))
            page.goto((out / 'comparison.html').as_uri(), wait_until='load')
            assert page.locator('#paired').inner_text() == 'What the precision costs'
            images = page.locator('.thumbs img')
            assert images.count() == len(paired.worst)
            widths = images.evaluate_all('(all) => all.map((i) => i.naturalWidth)')
            assert all(w > 0 for w in widths)
            assert all(u.startswith(('file:', 'data:')) for u in requests)
            text = page.locator('main').inner_text()
            assert f'[{paired.ci[0]:+.4f}, {paired.ci[1]:+.4f}]' in text
        finally:
            browser.close()


def test_a_run_whose_bag_is_gone_says_why_it_has_no_paired_interval(tmp_path: Path) -> None:
    bag = tmp_path / 'bag.mcap'
    shutil.copyfile(RAW, bag)
    rb.run(bag, backends=['hsv', 'onnx-cpu'], out=tmp_path / 'run')
    bag.unlink()
    comparison = rb.compare(tmp_path / 'run', baseline_backend='hsv')
    row = _row(comparison, 'onnx_cpu')
    assert row.paired is not None
    assert row.paired.ci is None
    assert 'not found' in row.paired.note
    assert any(f.startswith('paired accuracy interval not made') for f in row.flags)
    assert row.metrics['map50'].diff is not None  # the run.json change stays


def test_importing_compare_loads_neither_the_pairing_nor_a_bag_reader() -> None:
    code = (
        'import sys, replaybench.comparison, replaybench.app.compare\n'
        "heavy = ['replaybench.comparison.paired', 'mcap', 'cv2', 'replaybench.sources.mcap']\n"
        'print([m for m in heavy if m in sys.modules])'
    )
    out = subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert out == '[]'


# -- label masks ------------------------------------------------------------------------------

MASKS = REPO / 'fixtures' / 'bags' / 'live_masks.mcap'
IMAGES = '/camera/image_raw/compressed'


@pytest.fixture(scope='module')
def mask_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``two``: hsv-seg and onnx-seg (the bundled segmenter) in one run; ``hsv``: hsv-seg
    alone, another run of the same bag."""
    base = tmp_path_factory.mktemp('paired-masks')
    two, alone = base / 'two', base / 'hsv'
    rb.run(MASKS, backends=['hsv-seg', 'onnx-seg'], topics=IMAGES, out=two)
    rb.run(MASKS, backends='hsv-seg', topics=IMAGES, out=alone)
    return {'two': two, 'hsv': alone}


def _mono8(path: Path, topic: str) -> dict[tuple[str, int], np.ndarray]:
    from replaybench.decode import decode_image

    with open_source(path) as source:
        frames = [decode_image(raw) for raw in source.messages(topics=[topic])]
    return {
        (f.frame_id, f.stamp_ns): np.asarray(f.image).reshape(f.image.shape[:2]) for f in frames
    }


def test_two_segmenters_get_the_miou_change_and_the_interval_of_a_direct_paired_bootstrap(
    mask_runs: dict[str, Path], tmp_path: Path
) -> None:
    from replaybench.tasks.segmentation.scoring import confusion, scores
    from replaybench.tasks.segmentation.sink import labels_channel

    resamples = 200
    comparison = compare_runs(
        [mask_runs['two']], baseline_backend='hsv_seg', paired_resamples=resamples
    )
    row = next(r for r in comparison.rows if r.backend == 'onnx_seg')
    paired = row.paired
    assert paired is not None
    assert paired.metric == 'miou'
    # the independent computation: full 256 x 256 matrices per frame, summed over each draw
    hsv = _mono8(mask_runs['two'] / 'outputs.mcap', labels_channel('hsv_seg', IMAGES))
    onnx = _mono8(mask_runs['two'] / 'outputs.mcap', labels_channel('onnx_seg', IMAGES))
    truth = _mono8(MASKS, '/ground_truth/labels')
    keys = sorted(k for k in truth if k in hsv and k in onnx)
    n = len(keys)
    matrices = {
        name: np.stack([confusion(masks[k], truth[k]) for k in keys])
        for name, masks in (('hsv', hsv), ('onnx', onnx))
    }
    draws = np.random.default_rng(0).integers(0, n, size=(resamples, n))
    changes = [
        scores(matrices['onnx'][p].sum(axis=0)).miou - scores(matrices['hsv'][p].sum(axis=0)).miou  # type: ignore[operator]
        for p in draws
    ]
    lo, hi = np.quantile(changes, [0.025, 0.975])
    assert paired.frames == n == 10
    assert paired.ci is not None
    assert paired.ci[0] == pytest.approx(lo, abs=1e-12)
    assert paired.ci[1] == pytest.approx(hi, abs=1e-12)
    run = rb.load_run(mask_runs['two'])
    by_backend = {s.backend: s.miou for s in run.summary_rows}
    assert paired.baseline == pytest.approx(by_backend['hsv_seg'], abs=1e-12)
    assert paired.candidate == pytest.approx(by_backend['onnx_seg'], abs=1e-12)
    assert row.metrics['miou'].diff_ci == paired.ci
    assert paired.ci[1] < 0.0  # the bundled segmenter is a little less exact than hsv-seg here
    # pixel agreement: the run's own figure (its frames are all of one size)
    (agreement,) = run.segmentation_agreement
    assert paired.matched_mean == pytest.approx(agreement.pixel_agreement, abs=1e-9)
    assert paired.matched_min is not None
    assert paired.matched_min < 1.0
    # the page draws the least agreeing frames: image beside both masks
    out = tmp_path / 'cmp'
    rb.compare(mask_runs['two'], baseline_backend='hsv_seg', out=out)
    page = (out / 'comparison.html').read_text()
    section = page[page.index('id="paired"') :]
    assert section.count('<img src="data:image/jpeg;base64,') == len(paired.worst) > 0
    assert 'masks agree: pixels' in section


def test_the_same_segmenter_over_the_same_frames_changes_nothing_and_agrees_fully(
    mask_runs: dict[str, Path],
) -> None:
    comparison = rb.compare(mask_runs['two'], mask_runs['hsv'])
    paired = _row(comparison, 'hsv_seg').paired
    assert paired is not None
    assert paired.metric == 'miou'
    assert paired.change == 0.0
    assert paired.ci == (0.0, 0.0)
    assert paired.matched_mean == paired.iou_mean == 1.0
    assert paired.worst == ()
