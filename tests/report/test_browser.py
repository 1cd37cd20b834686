"""report.html in a real browser: headless Chromium (Debian package) driven by playwright.

Locally the module is skipped when /usr/bin/chromium or the playwright package is missing.
With the environment variable CI set, a missing browser fails instead, so CI cannot skip it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.app.run import RunConfig, run_benchmark

if TYPE_CHECKING:
    from collections.abc import Iterator

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'fixtures' / 'bags' / 'two_camera.mcap'
CHROMIUM = Path('/usr/bin/chromium')
CHROMIUM_ARGS = [
    '--no-sandbox',
    '--disable-gpu',
    '--disable-quic',
    '--no-first-run',
    '--disable-background-networking',
    '--disable-component-update',
    '--disable-sync',
]
BACKENDS = ('hsv', 'null')
TOPICS = ('/cam_left/image_raw/compressed', '/cam_right/image_raw/compressed')
PNG_SIGNATURE = b'\x89PNG\r\n\x1a\n'


def _in_ci() -> bool:
    return os.environ.get('CI', '').strip().lower() not in ('', '0', 'false', 'no')


def _require_browser() -> None:
    missing = []
    if not CHROMIUM.is_file():
        missing.append(f'{CHROMIUM} is missing (apt-get install -y chromium)')
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing.append('the playwright package is missing (pip install playwright)')
    if not missing:
        return
    reason = '; '.join(missing)
    if _in_ci():
        pytest.fail(f'browser test cannot run in CI: {reason}', pytrace=False)
    pytest.skip(f'browser test needs a browser: {reason}')


class Page:
    """The loaded report and what the browser reported while loading it."""

    def __init__(self, page: Any, run_dir: Path) -> None:
        self.page = page
        self.run_dir = run_dir
        self.errors: list[str] = []
        self.requests: list[str] = []


@pytest.fixture(scope='module')
def report(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Page]:
    """`replaybench run two_camera.mcap -b hsv -b null`, its report.html open in Chromium."""
    _require_browser()
    from playwright.sync_api import sync_playwright

    run_dir = tmp_path_factory.mktemp('browser') / 'run'
    outcome = run_benchmark(
        RunConfig(
            inputs=[BAG],
            backends=list(BACKENDS),
            out_dir=run_dir,
            command=['replaybench', 'run', str(BAG), '-b', 'hsv', '-b', 'null'],
        )
    )
    assert outcome.status == 'complete'
    html = run_dir / 'report.html'
    assert html.is_file()
    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True
        )
        try:
            page = browser.new_page(viewport={'width': 1280, 'height': 900})
            loaded = Page(page, run_dir)
            page.on(
                'console',
                lambda m: (
                    loaded.errors.append(f'console {m.type}: {m.text}')
                    if m.type in ('error', 'assert')
                    else None
                ),
            )
            page.on('pageerror', lambda e: loaded.errors.append(f'page error: {e}'))
            page.on('requestfailed', lambda r: loaded.errors.append(f'request failed: {r.url}'))
            page.on('request', lambda r: loaded.requests.append(r.url))
            page.goto(html.as_uri(), wait_until='load', timeout=30_000)
            yield loaded
        finally:
            browser.close()


def test_report_loads_without_console_or_page_errors(report: Page) -> None:
    assert report.page.title().startswith('replaybench report')
    assert report.errors == []


def test_report_fetches_nothing_but_itself_and_data_uris(report: Page) -> None:
    assert report.requests[0].startswith('file://')
    assert [u for u in report.requests[1:] if not u.startswith('data:')] == []


def test_every_chart_renders_with_a_visible_size_and_drawn_content(report: Page) -> None:
    charts: list[dict[str, float]] = report.page.eval_on_selector_all(
        'svg:not(svg svg)',
        """els => els.map(el => {
            const box = el.getBoundingClientRect();
            const content = el.getBBox();
            return {width: box.width, height: box.height,
                    contentWidth: content.width, contentHeight: content.height,
                    marks: el.querySelectorAll('polyline, path, rect, line, circle').length,
                    words: el.textContent.includes('Too few points to show a trend')};
        })""",
    )
    # per topic: latency over time, latency CDF, detections over time; throughput and stages
    assert len(charts) >= 3 * len(TOPICS) + 2
    for chart in charts:
        assert chart['width'] > 50, chart
        assert chart['height'] > 50, chart
        assert chart['contentWidth'] > 0, chart
        assert chart['contentHeight'] > 0, chart
        # drawn, or (a chart over time of a few samples, such as a short run's resource use)
        # its points said in words
        assert chart['marks'] > 0 or chart['words'], chart


def test_summary_table_has_one_row_per_backend_and_topic(report: Page) -> None:
    rows: list[list[str]] = report.page.eval_on_selector_all(
        '#summary-table tbody tr',
        'rows => rows.map(r => Array.from(r.cells, c => c.innerText.trim()))',
    )
    # with several camera topics, each backend's rig row (all its cameras) too
    rig = ['rig'] if len(TOPICS) > 1 else []
    assert sorted((row[0], row[1]) for row in rows) == sorted(
        (backend, topic) for backend in BACKENDS for topic in [*TOPICS, *rig]
    )
    for row in rows:
        assert int(row[2]) > 0  # measured frames


def test_sample_images_are_decoded_by_the_browser(report: Page) -> None:
    images: list[dict[str, Any]] = report.page.eval_on_selector_all(
        'figure img',
        """imgs => imgs.map(i => ({complete: i.complete, width: i.naturalWidth,
                                   height: i.naturalHeight, src: i.src.slice(0, 23)}))""",
    )
    assert len(images) == len(TOPICS)
    for image in images:
        assert image['complete'], image
        assert image['width'] > 0, image
        assert image['height'] > 0, image
        assert image['src'] == 'data:image/jpeg;base64,', image


def test_full_page_screenshot_is_a_png(report: Page) -> None:
    path = report.run_dir / 'report.png'
    report.page.screenshot(path=str(path), full_page=True)
    data = path.read_bytes()
    assert data.startswith(PNG_SIGNATURE)
    assert len(data) > 10_000
    width = int.from_bytes(data[16:20], 'big')
    height = int.from_bytes(data[20:24], 'big')
    assert width >= 1280
    assert height > 900  # the full page is longer than the viewport
