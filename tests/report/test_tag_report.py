"""The report's tag accuracy section: a replay of a tag bag through both tag backends, its
report.html opened in Chromium (skipped locally without the browser, as test_browser.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from replaybench.app.run import run_benchmark, run_config
from replaybench.fixtures.tags import write_tag_mcap

if TYPE_CHECKING:
    from pathlib import Path

CHROMIUM = '/usr/bin/chromium'
CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--no-first-run']


def _require_browser() -> None:
    import os
    import pathlib

    missing = []
    if not pathlib.Path(CHROMIUM).is_file():
        missing.append(f'{CHROMIUM} is missing')
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing.append('the playwright package is missing')
    if missing:
        if os.environ.get('CI', '').strip().lower() not in ('', '0', 'false', 'no'):
            pytest.fail(f'browser test cannot run in CI: {"; ".join(missing)}', pytrace=False)
        pytest.skip(f'browser test needs a browser: {"; ".join(missing)}')


@pytest.fixture(scope='module')
def tag_report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp('tagreport')
    bag = write_tag_mcap(base / 'tags.mcap', 4)
    config = run_config(
        bag,
        backends=['apriltag', 'aruco', 'hsv'],
        out=base / 'run',
        warmup=0,
        tag_size=0.16,
        tag_sizes='14=0.2,3=0.1',
    )
    assert run_benchmark(config).status == 'complete'
    return base / 'run' / 'report.html'


def test_the_report_has_a_tag_accuracy_row_per_tag_backend_and_none_for_others(
    tag_report: Path,
) -> None:
    html = tag_report.read_text(encoding='utf-8')
    assert '<h2 id="tags">Tag accuracy</h2>' in html
    start = html.index('id="tag-accuracy"')
    section = html[start : html.index('</table>', start)]
    assert section.count('<tr><td>') == 2
    assert '<tr><td>apriltag</td>' in section
    assert '<tr><td>aruco</td>' in section
    assert '<tr><td>hsv</td>' not in section


def test_the_tag_section_renders_in_a_browser(tag_report: Path) -> None:
    _require_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={'width': 1280, 'height': 900})
            errors: list[str] = []
            page.on('pageerror', lambda e: errors.append(str(e)))
            page.goto(tag_report.as_uri(), wait_until='load', timeout=30_000)
            table = page.locator('#tag-accuracy')
            assert table.is_visible()
            rows = table.locator('tbody tr')
            assert rows.count() == 2
            recall = rows.nth(0).locator('td').nth(2).inner_text()
            assert recall == '1.000'  # frames 0-3: no tag hidden
            assert errors == []
        finally:
            browser.close()
