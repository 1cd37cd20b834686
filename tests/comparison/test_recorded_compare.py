"""compare and its gate on the recorded backend's latency from the recording.

Bags are written with the real live writer (``write_live_mcap``) at known log times: the same
scene and seed, the node's pipeline 33 ms and more in one bag and 50 ms and more in the other
(the same spread and stalls, 17 ms later each), so every recorded latency, median and ratio is
known from ``live_timings``; each is replayed by the ``recorded`` backend into a run folder.
"""

from __future__ import annotations

import csv
import json
from typing import TYPE_CHECKING

import numpy as np
import pytest

import replaybench as rb
from replaybench.comparison.output import CSV_COLUMNS, PAIRED_COLUMNS
from replaybench.fixtures.live import live_timings, write_live_mcap

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.results.model import Comparison, ComparisonRow

FRAMES = 40
SIZE = (96, 72)
FAST_MS, SLOW_MS = 33, 50
CHROMIUM_PATH = '/usr/bin/chromium'


def _expected(frames: int, base_ms: int) -> tuple[list[float], list[float]]:
    """Pipeline and capture-to-output latencies (ms) of the outputs written, in log-time order."""
    timings = [t for t in live_timings(frames, base_ms=base_ms) if t.output_log_ns is not None]
    pipeline = [(t.output_log_ns - t.image_log_ns) / 1e6 for t in timings if t.output_log_ns]
    capture = [(t.output_log_ns - t.stamp_ns) / 1e6 for t in timings if t.output_log_ns]
    return pipeline, capture


def _run(
    base: Path, name: str, frames: int, base_ms: int, backends: str = 'recorded', repeat: int = 1
) -> Path:
    bag = write_live_mcap(base / f'{name}.mcap', frames, SIZE, base_ms=base_ms)
    out = base / name
    rb.run(bag, backends=backends.split(','), out=out, report=False, repeat=repeat)
    return out


@pytest.fixture(scope='module')
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp('recorded-compare')
    return {
        'fast': _run(base, 'fast', FRAMES, FAST_MS, 'recorded,null'),
        'fast-again': _run(base, 'fast-again', FRAMES, FAST_MS),
        'fast-twice': _run(base, 'fast-twice', FRAMES, FAST_MS, repeat=2),
        'slow': _run(base, 'slow', FRAMES, SLOW_MS),
        'short-fast': _run(base, 'short-fast', 3, FAST_MS),
        'short-slow': _run(base, 'short-slow', 3, SLOW_MS),
        # a recorder whose clock is behind the node's: every output logged before its image
        'inverted': _run(base, 'inverted', FRAMES, -50),
    }


def _row(comparison: Comparison, backend: str = 'recorded') -> ComparisonRow:
    return next(r for r in comparison.rows if r.role == 'candidate' and r.backend == backend)


def _block_interval(x: list[float], y: list[float]) -> tuple[float, float]:
    """The 95 % interval of 4 blocks against 4: the least and the greatest of the 16 ratios of
    block medians (2 / C(8, 4) = 2.9 %: only the extremes are excluded at 95 %)."""
    bx = [float(np.median(b)) for b in np.array_split(np.asarray(x), 4)]
    by = [float(np.median(b)) for b in np.array_split(np.asarray(y), 4)]
    ratios = [b / a for a in bx for b in by]
    return min(ratios), max(ratios)


def test_two_recordings_compare_their_exact_recorded_medians_and_ratio(
    runs: dict[str, Path],
) -> None:
    fast_pipe, fast_cap = _expected(FRAMES, FAST_MS)
    slow_pipe, slow_cap = _expected(FRAMES, SLOW_MS)
    assert len(fast_pipe) == len(slow_pipe) == 36  # 4 frames of 40 without an output
    comparison = rb.compare(runs['fast'], runs['slow'])
    row = _row(comparison)
    pipe = row.metrics['recorded_pipeline_ms']
    assert pipe.value == pytest.approx(float(np.percentile(slow_pipe, 50)))
    assert pipe.baseline == pytest.approx(float(np.percentile(fast_pipe, 50)))
    assert pipe.baseline == pytest.approx(37.6525)
    assert pipe.value == pytest.approx(37.6525 + 17)
    assert pipe.ratio == pytest.approx(54.6525 / 37.6525)
    assert pipe.diff == pytest.approx(17.0)
    assert pipe.method == 'between-block'
    assert pipe.blocks == (4, 4)
    assert pipe.ratio_ci == pytest.approx(_block_interval(fast_pipe, slow_pipe))
    assert pipe.significant is True
    cap = row.metrics['recorded_capture_ms']
    assert cap.value == pytest.approx(float(np.percentile(slow_cap, 50)))
    assert cap.baseline == pytest.approx(float(np.percentile(fast_cap, 50)))
    p99 = row.metrics['recorded_pipeline_p99_ms']
    assert p99.value == pytest.approx(float(np.percentile(slow_pipe, 99)))
    assert row.metrics['recorded_capture_p99_ms'].baseline == pytest.approx(
        float(np.percentile(fast_cap, 99))
    )
    # the value and its interval are summary.csv's
    summary = json.loads((runs['slow'] / 'run.json').read_text())['summary'][0]
    assert pipe.value == pytest.approx(summary['pipeline_ms_p50'])
    assert pipe.value_ci == pytest.approx(
        [summary['pipeline_ms_p50_ci_low'], summary['pipeline_ms_p50_ci_high']]
    )
    # the replay's own timing stays empty for a recording
    assert row.metrics['median_ms'].value is None


def test_the_gate_fails_a_recording_30_percent_slower_and_passes_the_same_recording(
    runs: dict[str, Path],
) -> None:
    slower = rb.compare(runs['fast'], runs['slow'], fail_if='recorded_pipeline_ms > +30%')
    assert slower.gate is not None
    [check] = [c for c in slower.gate.results if c.backend == 'recorded']
    assert check.verdict == 'failed'
    low, high = _block_interval(*(_expected(FRAMES, ms)[0] for ms in (FAST_MS, SLOW_MS)))
    assert check.ci_low is not None
    assert check.ci_low == pytest.approx((low - 1) * 100)  # +36.8 %: the whole CI past +30 %
    assert check.ci_high == pytest.approx((high - 1) * 100)
    assert check.ci_low > 30
    assert 'recorded median pipeline latency 54.65 ms vs 37.65 ms baseline' in check.explanation
    assert check.method == 'between-block 4/4'

    same = rb.compare(
        runs['fast'],
        runs['fast-again'],
        fail_if=['recorded_pipeline_ms > +10%', 'recorded_capture_ms > +10%'],
    )
    assert same.verdict == 'passed'
    row = _row(same)
    assert row.metrics['recorded_pipeline_ms'].ratio == 1.0
    assert row.metrics['recorded_pipeline_ms'].significant is False


def test_a_p99_of_four_blocks_straddling_the_threshold_is_inconclusive(
    runs: dict[str, Path],
) -> None:
    comparison = rb.compare(runs['fast'], runs['slow'], fail_if='recorded_pipeline_p99_ms > +30%')
    assert comparison.verdict == 'inconclusive'
    [check] = comparison.gate.results if comparison.gate else []
    assert check.ci_low is not None
    assert check.ci_high is not None
    assert check.ci_low < 30 < check.ci_high
    assert 'the CI straddles +30%' in check.explanation


def test_three_outputs_against_three_are_inconclusive_however_slower(
    runs: dict[str, Path],
) -> None:
    fast, _ = _expected(3, FAST_MS)
    slow, _ = _expected(3, SLOW_MS)
    comparison = rb.compare(
        runs['short-fast'], runs['short-slow'], fail_if='recorded_pipeline_ms > +30%'
    )
    row = _row(comparison)
    pipe = row.metrics['recorded_pipeline_ms']
    assert pipe.ratio is not None
    assert pipe.ratio == pytest.approx(float(np.median(slow)) / float(np.median(fast)))
    assert pipe.ratio > 1.4
    assert pipe.method == 'per-frame'
    assert pipe.ratio_ci is None
    assert comparison.verdict == 'inconclusive'
    [check] = comparison.gate.results if comparison.gate else []
    assert 'no CI: 3 baseline against 3 recorded outputs are too few' in check.explanation
    assert any('3 recorded outputs: fewer than 20' in flag for flag in row.flags)


def test_a_refused_recording_has_no_recorded_metric_and_the_gate_says_why(
    runs: dict[str, Path],
) -> None:
    comparison = rb.compare(runs['fast'], runs['inverted'], fail_if='recorded_pipeline_ms > +10%')
    row = _row(comparison)
    for metric in ('recorded_pipeline_ms', 'recorded_capture_p99_ms'):
        m = row.metrics[metric]
        assert m.value is None
        assert m.ratio is None
        assert m.ratio_ci is None
        assert m.baseline is not None
    assert comparison.verdict == 'inconclusive'
    [check] = comparison.gate.results if comparison.gate else []
    assert 'this row has no recorded median pipeline latency: pipeline latency not reported' in (
        check.explanation
    )
    assert 'were logged before their image' in check.explanation
    assert any(f.startswith('recorded latency: pipeline latency not reported') for f in row.flags)


def test_a_replayed_backend_against_a_recording_shows_the_recording_beside_its_latency(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    pipeline, _ = _expected(FRAMES, FAST_MS)
    comparison = rb.compare(
        runs['fast'],
        baseline_backend='recorded',
        fail_if='recorded_pipeline_ms > +10%',
        out=tmp_path / 'cmp',
        markdown=tmp_path / 'cmp.md',
    )
    row = _row(comparison, 'null')
    m = row.metrics['recorded_pipeline_ms']
    assert m.value is None
    assert m.baseline == pytest.approx(float(np.percentile(pipeline, 50)))
    assert m.ratio is None
    assert row.metrics['median_ms'].value is not None  # its own, replayed latency
    assert comparison.verdict == 'inconclusive'  # never failed: a replay has no recording
    [check] = comparison.gate.results if comparison.gate else []
    assert 'this row (null) replays' in check.explanation
    with (tmp_path / 'cmp' / 'comparison.csv').open(newline='') as f:
        [record] = [r for r in csv.DictReader(f) if r['backend'] == 'null']
    assert float(record['recorded_pipeline_ms_baseline']) == pytest.approx(m.baseline, abs=1e-3)
    assert record['recorded_pipeline_ms'] == ''
    assert float(record['median_ms']) > 0
    text = (tmp_path / 'cmp.md').read_text(encoding='utf-8')
    assert f'{m.baseline:.4g} ms in the baseline recording (this row replays)' in text
    # comparison.html: the recording's pipeline latency charted beside null's own latency
    page = (tmp_path / 'cmp' / 'comparison.html').read_text(encoding='utf-8')
    assert '· recorded pipeline</text>' in page
    assert f'>{m.baseline:.4g}</text>' in page  # its p50 bar


def test_a_recordings_fps_is_no_speed_to_compare_with(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    """The rate the recorded backend was replayed at is how fast the bag was read: a recorded
    row has no FPS, and a replayed row's FPS is no ratio to it (nor is one recording's to
    another's)."""
    against = rb.compare(runs['fast'], baseline_backend='recorded', out=tmp_path / 'cmp')
    base = next(r for r in against.rows if r.role == 'baseline')
    assert base.backend == 'recorded'
    assert base.metrics['fps'].value is None
    null = _row(against, 'null')
    assert null.metrics['fps'].value is not None  # its own replay speed
    assert null.metrics['fps'].ratio is None
    assert null.metrics['fps'].baseline is None
    with (tmp_path / 'cmp' / 'comparison.csv').open(newline='') as f:
        records = {r['backend']: r for r in csv.DictReader(f)}
    assert records['recorded']['fps'] == ''
    assert records['null']['fps_ratio'] == ''
    two = rb.compare(runs['fast'], runs['slow'])
    assert _row(two).metrics['fps'].value is None
    assert _row(two).metrics['fps'].ratio is None


def test_every_exporter_carries_the_recorded_metrics(runs: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / 'cmp'
    comparison = rb.compare(
        runs['fast'],
        runs['slow'],
        fail_if='recorded_pipeline_ms > +30%',
        out=out,
        markdown=tmp_path / 'cmp.md',
    )
    row = _row(comparison)
    pipe = row.metrics['recorded_pipeline_ms']
    assert pipe.ratio is not None
    # comparison.csv: the new columns after every earlier one
    with (out / 'comparison.csv').open(newline='') as f:
        reader = csv.reader(f)
        header = next(reader)
        rows = [dict(zip(header, r, strict=True)) for r in reader]
    assert tuple(header) == CSV_COLUMNS
    assert header.index('tag_rot_err_deg_delta') < header.index('recorded_pipeline_ms')
    rig = header.index('rig_p99_ms')  # the rig's columns appended after them
    assert header[rig - 3 : rig] == [
        'recorded_ci_method',
        'recorded_outputs',
        'recorded_latency_note',
    ]
    paired = len(PAIRED_COLUMNS)  # the paired columns appended last
    assert header[-3 - paired : -paired] == [
        'rig_drop_rate',
        'rig_drop_rate_baseline',
        'rig_drop_rate_delta',
    ]
    assert header[-paired:] == list(PAIRED_COLUMNS)
    [record] = [r for r in rows if r['role'] == 'candidate' and r['backend'] == 'recorded']
    assert float(record['recorded_pipeline_ms_ratio']) == pytest.approx(pipe.ratio, rel=1e-5)
    assert pipe.ratio_ci is not None
    assert float(record['recorded_pipeline_ms_ci_low']) == pytest.approx(pipe.ratio_ci[0], 1e-5)
    assert record['recorded_pipeline_ms_significant'] == 'yes'
    assert record['recorded_ci_method'] == 'between-block 4/4'
    assert record['recorded_outputs'] == '36'
    assert record['gate'] == 'failed'
    # comparison.json: the metrics by name (the schema is checked as the file is written)
    document = json.loads((out / 'comparison.json').read_text())
    [found] = [
        r for r in document['rows'] if r['role'] == 'candidate' and r['backend'] == 'recorded'
    ]
    assert found['metrics']['recorded_pipeline_ms']['ratio'] == pytest.approx(pipe.ratio)
    assert found['metrics']['recorded_pipeline_ms']['method'] == 'between-block'
    assert 'recorded_* metrics' in document['statistics']['recorded']
    # --markdown: the recorded columns
    text = (tmp_path / 'cmp.md').read_text(encoding='utf-8')
    assert '| recorded pipeline | recorded capture-to-output | method |' in text
    assert f'×{pipe.ratio:.3f} [{pipe.ratio_ci[0]:.3f}, {pipe.ratio_ci[1]:.3f}]' in text
    # comparison.html, in a real browser
    _check_html(out / 'comparison.html', pipe.ratio)


def _check_html(path: Path, ratio: float) -> None:
    from pathlib import Path as _Path

    if not _Path(CHROMIUM_PATH).is_file():
        pytest.skip(f'{CHROMIUM_PATH} is missing (apt-get install -y chromium)')
    playwright = pytest.importorskip('playwright.sync_api')
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=CHROMIUM_PATH, args=['--no-sandbox', '--disable-gpu'], headless=True
        )
        try:
            page = browser.new_page(viewport={'width': 1280, 'height': 900})
            page.goto(path.as_uri(), wait_until='load')
            table = page.locator('table.summary')
            heads = table.locator('thead th').all_inner_texts()
            assert 'RECORDED PIPELINE MS' in [h.upper() for h in heads]
            column = [h.upper() for h in heads].index('RECORDED PIPELINE MS')
            candidate = table.locator('tbody tr', has_text='candidate').first
            cell = candidate.locator('td').nth(column).inner_text()
            assert f'×{ratio:.3f}' in cell
            assert 'significant' in cell
        finally:
            browser.close()


def test_the_command_line_gate_exits_1_on_a_slower_recording(runs: dict[str, Path]) -> None:
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', 'compare', str(runs['fast']), str(runs['slow']),
         '--fail-if', 'recorded_pipeline_ms > +30%'],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert done.returncode == 1, done.stderr
    assert 'recorded pipeline ×1.451 [1.368, 1.549]' in done.stdout
    assert '[between-block 4/4]' in done.stdout
    assert 'FAIL recorded_pipeline_ms > +30%' in done.stdout + done.stderr


def test_passes_of_repeat_hold_a_recording_once(runs: dict[str, Path]) -> None:
    """Every pass replays the same recorded latencies: compared once, not as twice the
    evidence (a narrower interval)."""
    once = _row(rb.compare(runs['fast'], runs['fast-again'])).metrics['recorded_pipeline_ms']
    row = _row(rb.compare(runs['fast'], runs['fast-twice']))
    twice = row.metrics['recorded_pipeline_ms']
    assert twice.ratio == 1.0
    assert twice.ratio_ci == once.ratio_ci
    assert twice.blocks == (4, 4)
    record = next(
        r
        for r in rb.compare(runs['fast'], runs['fast-twice']).table_rows or []
        if r['role'] == 'candidate'
    )
    assert record['recorded_outputs'] == 36


@pytest.mark.parametrize('task', ['tags', 'masks'])
def test_recorded_tags_and_masks_compare_on_their_recorded_latency(
    task: str, tmp_path: Path
) -> None:
    from replaybench.fixtures.live_tasks import (
        LIVE_MASK_TOPIC,
        mask_timings,
        tag_timings,
        write_live_mask_mcap,
        write_live_tag_mcap,
    )

    frames = 24
    if task == 'tags':
        bag = write_live_tag_mcap(tmp_path / 'tags.mcap', frames, (320, 240))
        timings, topic = tag_timings(frames), None
    else:
        bag = write_live_mask_mcap(tmp_path / 'masks.mcap', frames, SIZE)
        timings, topic = mask_timings(frames), LIVE_MASK_TOPIC
    for name in ('a', 'b'):
        rb.run(bag, backends='recorded', out=tmp_path / name, report=False, recorded_topic=topic)
    pipeline = [(t.output_log_ns - t.image_log_ns) / 1e6 for t in timings if t.output_log_ns]
    capture = [(t.output_log_ns - t.stamp_ns) / 1e6 for t in timings if t.output_log_ns]
    row = _row(rb.compare(tmp_path / 'a', tmp_path / 'b'))
    assert row.metrics['recorded_pipeline_ms'].value == pytest.approx(
        float(np.percentile(pipeline, 50))
    )
    assert row.metrics['recorded_capture_p99_ms'].baseline == pytest.approx(
        float(np.percentile(capture, 99))
    )
    assert row.metrics['recorded_pipeline_ms'].ratio == 1.0
    assert row.metrics['recorded_pipeline_ms'].method == 'per-frame'  # under 20 outputs
    assert row.metrics['recorded_pipeline_ms'].significant is False
