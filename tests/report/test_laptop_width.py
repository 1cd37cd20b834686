"""The pages at a laptop's width (1366x768, headless Chromium): the figures read first are on
screen without scrolling sideways, on a machine with a long, odd name (tests/conftest.py).

Run report (boxes, tags, masks): measured frames, drops, FPS, p50, p99 and the task's main
accuracy (mAP@0.5, tag recall, mIoU); comparison: n, median, p99, FPS, mAP@0.5; peak: each
trial's frames, drops and p99; sweep: each cell's FPS, p50, p99 and mAP@0.5.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

import replaybench as rb
from replaybench.app.options import RunOptions
from replaybench.app.peak import find_peak_rate
from replaybench.app.run import RunConfig, run_benchmark
from replaybench.app.sweep.record import cell_metrics
from replaybench.backends.base import BackendOptions
from replaybench.report.sweep_html import render_sweep_html
from replaybench.results.model import Tool
from replaybench.results.sweepfile import (
    SweepCell,
    SweepCounts,
    SweepInput,
    SweepRecord,
    SweepSettings,
    write_sweep_result,
)

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / 'fixtures' / 'bags'
CHROMIUM = Path('/usr/bin/chromium')
WIDTH, HEIGHT = 1366, 768

#: Every column's cells (its header included) of the table ``table``, whose header is one of
#: ``names``, that end past the viewport's right edge or the right edge of the box that
#: scrolls them: those a reader would have to scroll to.
_OFF_SCREEN = """([table, names]) => {
    const t = document.querySelector(table);
    if (!t) return ['no ' + table];
    const heads = Array.from(t.tHead.rows[0].cells, c => c.innerText.trim());
    const missing = names.filter(n => !heads.includes(n));
    if (missing.length) return missing.map(n => 'no column ' + n + ' in ' + heads.join('|'));
    const wrap = t.closest('.table-wrap') || t.parentElement;
    const edge = Math.min(window.innerWidth, wrap.getBoundingClientRect().right);
    const out = [];
    for (const name of names) {
        const at = heads.indexOf(name);
        const cells = [t.tHead.rows[0].cells[at]];
        for (const row of t.tBodies[0].rows) {
            if (row.cells.length === heads.length) cells.push(row.cells[at]);
        }
        for (const cell of cells) {
            const box = cell.getBoundingClientRect();
            if (box.left < 0 || box.right > edge + 0.5) {
                out.push(name + ': ' + cell.innerText.trim() + ' ends at ' + box.right);
            }
        }
    }
    return out;
}"""

#: The figure lines of the sweep's cells that end past the viewport's right edge.
_SWEEP_OFF_SCREEN = """() => {
    const out = [];
    const lines = document.querySelectorAll('td.cell div.n, td.cell div.where');
    for (const line of lines) {
        const box = line.getBoundingClientRect();
        if (box.left < 0 || box.right > window.innerWidth + 0.5) {
            out.push(line.innerText + ' ends at ' + box.right);
        }
    }
    return out.length ? out : (lines.length ? [] : ['no figures']);
}"""


def _run(out: Path, bag: Path, backends: Sequence[str], **config: Any) -> Path:
    outcome = run_benchmark(RunConfig(inputs=[bag], backends=list(backends), out_dir=out, **config))
    assert outcome.run_dir is not None
    return outcome.run_dir


def _sweep_page(base: Path, bag: Path, backends: Sequence[str], host: str) -> Path:
    """sweep.html of one bag and ``backends``, each cell a real run folder, the sweep.json
    written by its writer (checked against its schema)."""
    from replaybench.results.folder import load_run

    cells = []
    for index, backend in enumerate(backends):
        folder = _run(base / f'cell-{backend}', bag, [backend])
        data = load_run(folder)
        key = f'{index:016x}' * 4
        cells.append(
            SweepCell(
                index=index,
                cell=f'0-{backend}',
                key=key,
                input=str(bag),
                input_index=0,
                backend=backend,
                status='complete',
                run_dir=folder.name,
                hostname=host,
                metrics=cell_metrics(data.run, data.frames, key),
            )
        )
    record = SweepRecord(
        tool=Tool(name='replaybench', version='0.1.0'),
        status='complete',
        command=('replaybench', 'sweep', str(bag)),
        started_at='2025-01-02T03:04:05+00:00',
        finished_at='2025-01-02T03:05:05+00:00',
        wall_s=60.0,
        settings=SweepSettings(backends=tuple(backends), options=RunOptions().as_dict()),
        inputs=(SweepInput(path=str(bag), resolved=str(bag), size_bytes=1, sha256='ab' * 32),),
        counts=SweepCounts(cells=len(cells), complete=len(cells)),
        cells=tuple(cells),
    )
    document = write_sweep_result(base / 'sweep.json', record)
    page = base / 'sweep.html'
    page.write_text(render_sweep_html(document), encoding='utf-8')
    return page


@pytest.fixture(scope='module')
def pages(
    tmp_path_factory: pytest.TempPathFactory, long_machine_name: tuple[str, str]
) -> dict[str, Path]:
    base = tmp_path_factory.mktemp('laptop')
    boxes = BAGS / 'live_detections.mcap'
    first = _run(base / 'boxes', boxes, ['recorded', 'hsv'])
    again = _run(base / 'boxes-again', boxes, ['recorded', 'hsv'])
    rb.compare(first, again, out=base / 'cmp')
    find_peak_rate(
        BAGS / 'ci.mcap',
        'null',
        base / 'peak',
        options=BackendOptions(),
        trial_frames=12,
        min_hz=40.0,
        max_hz=80.0,
        refine_steps=1,
    )
    return {
        'boxes': first / 'report.html',
        'tags': _run(base / 'tags', REPO / 'fixtures' / 'tags' / 'live_tags.mcap', ['recorded'])
        / 'report.html',
        'masks': _run(
            base / 'masks',
            BAGS / 'live_masks.mcap',
            ['recorded'],
            topics=['/camera/image_raw/compressed'],
            recorded_topic='/unet/raw_segmentation_mask',
        )
        / 'report.html',
        'comparison': base / 'cmp' / 'comparison.html',
        'peak': base / 'peak' / 'peak.html',
        'sweep': _sweep_page(
            base / 'sweep', boxes, ['hsv', 'null', 'recorded'], long_machine_name[0]
        ),
    }


@pytest.fixture(scope='module')
def browser() -> Iterator[Any]:
    if not CHROMIUM.is_file():
        pytest.skip(f'{CHROMIUM} is missing (apt-get install -y chromium)')
    playwright = pytest.importorskip('playwright.sync_api')
    with playwright.sync_playwright() as p:
        launched = p.chromium.launch(
            executable_path=str(CHROMIUM), args=['--no-sandbox', '--disable-gpu'], headless=True
        )
        try:
            yield launched
        finally:
            launched.close()


def _open(browser: Any, path: Path) -> Any:
    page = browser.new_page(viewport={'width': WIDTH, 'height': HEIGHT})
    page.goto(path.as_uri(), wait_until='load')
    return page


RUN_COLUMNS = ['measured', 'dropped', 'FPS', 'p50 ms', 'p99 ms']


@pytest.mark.parametrize(
    ('name', 'table', 'columns'),
    [
        ('boxes', '#summary-table', [*RUN_COLUMNS, 'mAP@0.5']),
        ('tags', '#summary-table', [*RUN_COLUMNS, 'tag recall']),
        ('masks', '#summary-table', [*RUN_COLUMNS, 'mIoU']),
        ('comparison', 'table.summary', ['n', 'median ms', 'p99 ms', 'FPS', 'mAP@0.5']),
        ('peak', '#trials ~ .table-wrap table', ['frames', 'dropped', 'p99 ms']),
    ],
)
def test_the_figures_read_first_are_on_screen_at_1366_px_without_scrolling(
    pages: dict[str, Path], browser: Any, name: str, table: str, columns: list[str]
) -> None:
    page = _open(browser, pages[name])
    try:
        assert page.evaluate(_OFF_SCREEN, [table, columns]) == []
        # nothing on the page is wider than the screen, the machine's long name included
        assert page.evaluate('document.documentElement.scrollWidth') <= WIDTH
    finally:
        page.close()


def test_every_sweep_cell_shows_its_figures_on_screen_at_1366_px(
    pages: dict[str, Path], browser: Any
) -> None:
    page = _open(browser, pages['sweep'])
    try:
        assert page.evaluate(_SWEEP_OFF_SCREEN) == []
        assert page.evaluate('document.documentElement.scrollWidth') <= WIDTH
        text = page.locator('table').first.inner_text()
        assert text.count('best FPS') == 1  # hsv or null: never the recording
        assert 'recorded outputs: no replay speed' in text
    finally:
        page.close()
