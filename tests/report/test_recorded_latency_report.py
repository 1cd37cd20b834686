"""Recorded latency beside replayed latency: the report's section (in Chromium) and the
terminal's lines, on the live fixture bag."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import pytest
from typer.testing import CliRunner

from replaybench.app.run import RunConfig, run_benchmark
from replaybench.cli import app
from replaybench.fixtures.live import write_live_mcap
from replaybench.report.formats import fmt_fps, fmt_ms
from replaybench.results.records import read_frames_csv

if TYPE_CHECKING:
    from replaybench.app.run import RunOutcome

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = Path('/usr/bin/chromium')


@pytest.fixture(scope='module')
def live_run(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    base = tmp_path_factory.mktemp('live')
    bag = write_live_mcap(base / 'live.mcap', 30, (96, 72))
    return run_benchmark(
        RunConfig(inputs=[bag], backends=['recorded', 'null'], out_dir=base / 'run')
    )


def test_the_report_shows_recorded_latency_beside_replayed_latency(live_run: RunOutcome) -> None:
    assert live_run.run_dir is not None
    html = (live_run.run_dir / 'report.html').read_text(encoding='utf-8')
    rec = next(r for r in live_run.run.summary_rows if r.backend == 'recorded')
    null = next(r for r in live_run.run.summary_rows if r.backend == 'null')
    section = html[html.index('<h2 id="recorded-latency">') : html.index('<h2 id="latency">')]
    assert section.count('<tr class="recorded">') == 2  # pipeline, capture-to-output
    assert section.count('<tr class="replayed">') == 1  # null
    assert f'<td class="n">{fmt_ms(rec.pipeline_ms_p50)}<br>' in section
    assert f'<td class="n">{fmt_ms(rec.capture_to_output_ms_p99)}<br>' in section
    assert f'<td class="n">{fmt_ms(null.latency_ms_p50)}<br>' in section
    assert f'<td class="n">{rec.recorded_outputs_dropped}</td>' in section
    assert 'Recorded and replayed latency CDF' in section


def test_a_refused_figure_shows_its_note_and_no_curve(tmp_path: Path) -> None:
    from replaybench.report import render_report
    from replaybench.results.recorded_latency import with_recorded_latency

    bag = write_live_mcap(tmp_path / 'live.mcap', 12, (96, 72))
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['recorded'], out_dir=tmp_path / 'run', report=False)
    )
    assert outcome.run_dir is not None
    # the same frames with the camera's clock 1 s ahead of the recorder's
    frames = [
        r._replace(stamp_ns=r.stamp_ns + 1_000_000_000) if r.stamp_ns else r
        for r in read_frames_csv(outcome.run_dir / 'frames.csv')
    ]
    [summary] = with_recorded_latency(outcome.summaries, frames)
    assert summary.recorded_outputs is not None
    assert summary.capture_to_output_ms_p50 is None
    note = summary.recorded_latency_note
    assert note is not None
    assert 'capture-to-output latency not reported' in note
    # the report drawn from the run folder says so
    page = render_report(outcome.run_dir).read_text(encoding='utf-8')
    assert 'id="recorded-latency"' in page
    assert 'recorded pipeline' in page


def test_run_prints_the_recorded_latency_after_its_table(tmp_path: Path) -> None:
    bag = REPO / 'fixtures' / 'bags' / 'live_detections.mcap'
    result = CliRunner().invoke(
        app,
        ['run', str(bag), '--backend', 'recorded', '--out', str(tmp_path / 'run'), '--no-report'],
    )
    assert result.exit_code == 0, result.output
    lines = [line for line in result.stdout.splitlines() if line.startswith('recorded latency')]
    assert len(lines) == 1
    assert lines[0].startswith(
        'recorded latency of recorded /camera/image_raw/compressed: 9 outputs, 1 frame(s) '
        'without one, '
    )
    assert 'pipeline p50 ' in lines[0]
    assert 'capture-to-output p50 ' in lines[0]
    assert 'recorded latency: 9 recorded outputs: fewer than 20, no 95 % interval' in (
        result.stderr
    )
    # the recorded row has no replay latency: no warning of its (zero) measured frames
    assert 'measured frames' not in result.stderr


def test_the_recorded_section_renders_in_chromium(live_run: RunOutcome) -> None:
    if not CHROMIUM.is_file():
        pytest.skip(f'{CHROMIUM} is missing (apt-get install -y chromium)')
    playwright = pytest.importorskip('playwright.sync_api')
    assert live_run.run_dir is not None
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM), args=['--no-sandbox', '--disable-gpu'], headless=True
        )
        try:
            page = browser.new_page(viewport={'width': 1280, 'height': 900})
            errors: list[str] = []
            page.on('pageerror', lambda e: errors.append(str(e)))
            page.goto((live_run.run_dir / 'report.html').as_uri(), wait_until='load')
            table = page.locator('#recorded-latency-table')
            assert table.is_visible()
            assert table.locator('tbody tr').count() == 3
            first = table.locator('tbody tr').first.inner_text()
            assert 'recorded pipeline' in first
            box = page.locator('#recorded-latency ~ .charts svg').first.bounding_box()
            assert box is not None
            assert box['width'] > 100
            assert errors == []
        finally:
            browser.close()


@pytest.fixture(scope='module')
def recorded_and_hsv(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    """`replaybench run live_detections.mcap --backend recorded --backend hsv`: the bag is
    read far faster than the robot's detector ran (26.65 Hz, 36.94 ms pipeline p50)."""
    bag = REPO / 'fixtures' / 'bags' / 'live_detections.mcap'
    out = tmp_path_factory.mktemp('recorded-hsv') / 'run'
    return run_benchmark(RunConfig(inputs=[bag], backends=['recorded', 'hsv'], out_dir=out))


def test_a_recording_is_never_the_fastest_and_shows_its_recorded_rate_and_latency(
    recorded_and_hsv: RunOutcome,
) -> None:
    from replaybench.report.headline import topic_headlines

    run = recorded_and_hsv.run
    assert recorded_and_hsv.run_dir is not None
    rec = next(r for r in run.summary_rows if r.backend == 'recorded')
    hsv = next(r for r in run.summary_rows if r.backend == 'hsv')
    assert rec.throughput_fps is not None
    assert hsv.throughput_fps is not None
    assert rec.recorded_output_hz == pytest.approx(26.65, abs=0.01)
    assert rec.pipeline_ms_p50 == pytest.approx(36.94, abs=0.01)
    [head] = topic_headlines(run, run.summary_rows, recorded_and_hsv.records)
    assert head.fastest == 'hsv'
    assert head.fps == hsv.throughput_fps
    html = (recorded_and_hsv.run_dir / 'report.html').read_text(encoding='utf-8')
    headline = html[html.index('<h2 id="headline">') : html.index('<div class="cards">')]
    assert '<td>hsv</td>' in headline
    assert '<td>recorded</td>' not in headline
    # the Summary: the recording's output rate and pipeline latency, marked recorded
    summary = html[html.index('id="summary-table"') : html.index('id="summary-more"')]
    row = summary[summary.index('recorded</td>') :].split('</tr>')[0]
    for value in (fmt_fps(rec.recorded_output_hz), fmt_ms(rec.pipeline_ms_p50)):
        assert f'>{value}<br><span class="muted">recorded</span></td>' in row
    assert fmt_fps(rec.throughput_fps) not in row  # how fast the bag was read: not a speed
    # the throughput and stage charts: replayed backends only, and the page says why
    charts = html[html.index('<h2 id="throughput">') : html.index('<h2 id="detections">')]
    assert '>hsv</text>' in charts
    assert '>recorded</text>' not in charts
    assert 'Not charted here: recorded, the outputs recorded in the bag' in charts


def test_the_terminal_marks_a_recordings_rate_and_latency_as_recorded(tmp_path: Path) -> None:
    bag = REPO / 'fixtures' / 'bags' / 'live_detections.mcap'
    result = CliRunner().invoke(
        app,
        ['run', str(bag), '-b', 'recorded', '-b', 'hsv', '--out', str(tmp_path / 'run'),
         '--no-report'],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    [row] = [
        line for line in lines if line.split()[:2] == ['recorded', '/camera/image_raw/compressed']
    ]
    assert row.split()[5:8] == ['26.7*', '36.94*', '47.20*']
    assert '* recorded: the output rate (Hz) and pipeline latency of the node that ran on the ' in (
        result.stdout
    )
    [hsv] = [line for line in lines if line.split()[:1] == ['hsv']]
    assert '*' not in hsv
