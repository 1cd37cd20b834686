"""The headline at the top of report.html: per topic the fastest backend with 95 % intervals,
the most accurate one, and how the two agree; one table that fits a laptop screen."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.comparison import compare_runs
from replaybench.report import render_report
from replaybench.report.headline import topic_headlines
from replaybench.results import write_json_atomic
from replaybench.results.folder import load_run

if TYPE_CHECKING:
    from collections.abc import Callable

    from playwright.sync_api import ViewportSize

    from replaybench.results.model import SummaryRow

    MakeRun = Callable[..., Path]

CHROMIUM = Path('/usr/bin/chromium')
LAPTOP: ViewportSize = {'width': 1366, 'height': 768}


def _patch(run_dir: Path, change: Callable[[dict[str, Any]], None]) -> None:
    path = run_dir / 'run.json'
    run = json.loads(path.read_text(encoding='utf-8'))
    change(run)
    write_json_atomic(path, run)


def _set_map50(values: dict[str, float]) -> Callable[[dict[str, Any]], None]:
    def change(run: dict[str, Any]) -> None:
        for row in run['summary']:
            if row['backend'] in values:
                row['accuracy'] = {'map50': values[row['backend']], 'precision50': 0.5}
                row['map50'] = values[row['backend']]

    return change


def _headline_rows(html: str) -> list[list[str]]:
    table = html[html.index('<table id="headline-table"') :]
    table = table[: table.index('</table>')]
    body = table[table.index('<tbody>') :]
    rows = []
    for row in re.findall(r'<tr>(.*?)</tr>', body):
        cells = re.findall(r'<td[^>]*>(.*?)</td>', row)
        rows.append([re.sub(r'<[^>]+>', ' ', c.replace('<wbr>', '')).split() for c in cells])
    return [[' '.join(c) for c in r] for r in rows]


def test_the_headline_names_the_fastest_detector_and_the_most_accurate_one_per_topic(
    make_run: MakeRun,
) -> None:
    run_dir = make_run(backends=('null', 'hsv', 'onnx-cpu'), frames=120)
    _patch(run_dir, _set_map50({'null': 0.0, 'hsv': 0.41, 'onnx-cpu': 0.77}))
    fps = {'null': 900.0, 'hsv': 412.25, 'onnx-cpu': 97.5}

    def throughput(run: dict[str, Any]) -> None:
        for row in run['summary']:
            row['throughput_fps'] = fps[row['backend']]

    _patch(run_dir, throughput)

    def agreement(run: dict[str, Any]) -> None:
        run['agreement'] = [
            {
                'backend_a': 'hsv',
                'backend_b': 'onnx-cpu',
                'topic': '/cam/front/image_raw',
                'matched_frac_a': 0.8,
                'matched_frac_b': 0.6,
                'mean_iou': 0.7,
            }
        ]

    _patch(run_dir, agreement)
    html = render_report(run_dir).read_text(encoding='utf-8')
    [row] = _headline_rows(html)
    assert row[0] == '/cam/front/image_raw'
    assert row[1] == 'hsv'  # null is the harness alone, not a detector
    assert row[5] == 'onnx-cpu'
    assert row[6] == '0.770'
    assert row[7] == '80 % of hsv’s boxes, 60 % of onnx-cpu’s matched, IoU 0.70'
    assert row[2].split()[0] == '412.2'
    # the headline comes first, before the cards and the summary table
    assert html.index('id="headline"') < html.index('class="cards"') < html.index('id="summary"')


def _fps(row: SummaryRow) -> float:
    """The row's throughput; every row of these runs has one."""
    assert row.throughput_fps is not None, row
    return row.throughput_fps


def test_the_intervals_are_the_ones_compare_gives_for_the_same_run(make_run: MakeRun) -> None:
    run_dir = make_run(backends=('hsv', 'onnx-cpu'), frames=150)
    data = load_run(run_dir)
    [head] = topic_headlines(data.run, data.run.summary_rows, data.frames)
    fps = {r.backend: _fps(r) for r in data.run.summary_rows}
    assert head.fastest == max(fps, key=fps.__getitem__)
    rows = compare_runs([run_dir]).rows
    mine = next(r for r in rows if r.backend == head.fastest)
    assert head.fps_ci == mine.metrics['fps'].value_ci
    assert head.p50_ci == mine.metrics['median_ms'].value_ci
    assert head.p99_ci == mine.metrics['p99_ms'].value_ci
    for value, interval in ((head.fps, head.fps_ci), (head.p50_ms, head.p50_ci)):
        assert interval is not None
        assert value is not None
        assert interval[0] <= value <= interval[1]
    html = render_report(run_dir).read_text(encoding='utf-8')
    lo, hi = head.fps_ci  # type: ignore[misc]
    assert f'{lo:.1f}–{hi:.1f}' in html
    # the same folder gives the same page
    assert render_report(run_dir).read_text(encoding='utf-8') == html


def test_a_short_run_shows_no_interval_rather_than_a_made_up_one(make_run: MakeRun) -> None:
    run_dir = make_run(frames=15)  # 12 measured frames after 3 of warm-up: under 20
    data = load_run(run_dir)
    [head] = topic_headlines(data.run, data.run.summary_rows, data.frames)
    assert head.fps is not None
    assert (head.fps_ci, head.p50_ci, head.p99_ci) == (None, None, None)
    html = render_report(run_dir).read_text(encoding='utf-8')
    [row] = _headline_rows(html)
    assert len(row[2].split()) == 1  # the value alone
    assert len(row) == 5  # no accuracy columns without ground truth, and a note saying so
    assert 'No ground truth in this run, so no accuracy' in html


def test_several_topics_say_what_a_topics_fps_is_next_to_the_number(make_run: MakeRun) -> None:
    topics = ('/cam/left/image_raw', '/cam/right/image_raw')
    run_dir = make_run(topics=topics, backends=('hsv', 'onnx-cpu'), frames=60)
    data = load_run(run_dir)
    heads = topic_headlines(data.run, data.run.summary_rows, data.frames)
    html = render_report(run_dir).read_text(encoding='utf-8')
    rows = _headline_rows(html)
    assert [r[0] for r in rows] == list(topics)
    for head, row in zip(heads, rows, strict=True):
        total = sum(_fps(r) for r in data.run.summary_rows if r.backend == head.fastest)
        assert head.fps_all == pytest.approx(total)
        assert row[2].endswith(f'of {total:.1f} in all')
    assert 'The topics are replayed together, interleaved, so they share that window' in html


def _require_browser() -> None:
    missing = []
    if not CHROMIUM.is_file():
        missing.append(f'{CHROMIUM} is missing (apt-get install -y chromium)')
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing.append('the playwright package is missing')
    if not missing:
        return
    if os.environ.get('CI', '').strip().lower() not in ('', '0', 'false', 'no'):
        pytest.fail(f'browser test cannot run in CI: {"; ".join(missing)}', pytrace=False)
    pytest.skip(f'browser test needs a browser: {"; ".join(missing)}')


def test_the_headline_fits_a_1366_pixel_laptop_screen_without_scrolling_sideways(
    make_run: MakeRun,
) -> None:
    _require_browser()
    from playwright.sync_api import sync_playwright

    topics = (
        '/robot/front_left_stereo_camera/image_rect_color/compressed',
        '/robot/rear_wide_angle_camera_with_a_long_name/image_raw',
        '/c',
    )
    backends = ('null', 'hsv-with-a-long-configuration-label', 'onnx-cpu')
    run_dir = make_run(topics=topics, backends=backends, frames=40)
    _patch(run_dir, _set_map50({'hsv-with-a-long-configuration-label': 0.5, 'onnx-cpu': 0.9}))
    report = render_report(run_dir)
    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM), args=['--no-sandbox', '--disable-gpu'], headless=True
        )
        try:
            page = browser.new_page(viewport=LAPTOP)
            page.goto(report.as_uri(), wait_until='load')
            sizes: dict[str, float] = page.evaluate(
                """() => {
                    const table = document.getElementById('headline-table');
                    const box = table.getBoundingClientRect();
                    return {tableScroll: table.scrollWidth, tableWidth: table.clientWidth,
                            right: box.right, bottom: box.bottom,
                            viewport: document.documentElement.clientWidth,
                            page: document.documentElement.scrollWidth,
                            rows: table.tBodies[0].rows.length};
                }"""
            )
            page.screenshot(path=str(run_dir / 'headline.png'))
        finally:
            browser.close()
    assert sizes['rows'] == len(topics)
    assert sizes['tableScroll'] <= sizes['tableWidth']
    assert sizes['right'] <= sizes['viewport'] == LAPTOP['width']
    assert sizes['page'] <= sizes['viewport']
    assert sizes['bottom'] <= 2 * LAPTOP['height']  # three topics in well under two screens


def test_the_most_accurate_backend_is_judged_by_the_first_task_figure_its_rows_have() -> None:
    from replaybench.report.headline import _judges, _most_accurate
    from replaybench.results.model import SummaryRow
    from replaybench.tasks import MetricSpec

    judges = _judges()
    assert [m.name for m in judges[:3]] == ['map50', 'tag_recall', 'miou']
    masks = [SummaryRow(backend='a', miou=0.4), SummaryRow(backend='b', miou=0.7)]
    best, spec = _most_accurate(masks, judges)
    assert (best.backend if best else None, spec.name if spec else None) == ('b', 'miou')
    boxes = [*masks, SummaryRow(backend='c', map50=0.1)]
    best, spec = _most_accurate(boxes, judges)  # the boxes' figure comes first
    assert (best.backend if best else None, spec.name if spec else None) == ('c', 'map50')
    error = MetricSpec('err', 'error', 'err', 'lower')
    rows = [SummaryRow(backend=n, task_metrics={'err': v}) for n, v in (('x', 2.0), ('y', 0.5))]
    best, spec = _most_accurate(rows, [error])
    assert best is not None
    assert best.backend == 'y'  # lower is better
    assert _most_accurate([SummaryRow(backend='z')], judges) == (None, None)
