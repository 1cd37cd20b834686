"""report.html of a segmentation run in headless Chromium: the mask thumbnail beside its frame."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from replaybench.app.run import RunConfig, run_benchmark
from replaybench.backends.hsv_seg import HsvSegBackend
from replaybench.fixtures.scene import Scene
from replaybench.fixtures.writer import write_mcap
from replaybench.segmentation.palette import palette
from replaybench.types import Frame

CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--no-first-run']
FRAMES = 5
SIZE = (160, 120)


@pytest.fixture(scope='module')
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp('report')
    bag = write_mcap(base / 'seg.mcap', FRAMES, SIZE, masks=True)
    out = base / 'run'
    run_benchmark(RunConfig(inputs=[bag], backends=['hsv-seg', 'hsv'], out_dir=out, warmup=1))
    return out


FRAME_REL = 'samples/input0_camera_image_raw.jpg'
MASK_REL = 'samples/input0_camera_image_raw.mask_hsv_seg.png'


def test_the_mask_thumbnail_is_the_palette_picture_of_the_sample_frames_mask(
    run_dir: Path,
) -> None:
    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    assert document['outputs']['samples'] == [FRAME_REL, MASK_REL]
    # below its 20 px title bar, the thumbnail is the palette picture of the frame's mask
    sample = FRAMES // 2
    image, _ = Scene(SIZE).render(sample)
    mask = HsvSegBackend().detect(Frame('/c', sample, 0, 0, 'c', image, 'bgr8', 'bgr8')).mask
    assert mask is not None
    thumb = cv2.imread(str(run_dir / MASK_REL), cv2.IMREAD_COLOR)
    assert thumb is not None
    assert np.array_equal(thumb[20 : 20 + SIZE[1]], palette()[mask.labels][:, :, ::-1])
    html = (run_dir / 'report.html').read_text(encoding='utf-8')
    (group,) = re.findall(r'<div class="samples">(.*?)</div>', html)
    assert re.findall(r'<figcaption>(.*?)</figcaption>', group) == [
        '/camera/image_raw',
        'hsv_seg mask',
    ]


def test_the_report_shows_the_mask_beside_its_frame_in_a_browser(run_dir: Path) -> None:
    chromium = Path('/usr/bin/chromium')
    playwright = pytest.importorskip('playwright.sync_api')
    if not chromium.is_file():
        pytest.skip(f'{chromium} is missing (apt-get install -y chromium)')
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(chromium), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page()
            errors: list[str] = []
            page.on('pageerror', lambda e: errors.append(str(e)))
            page.goto((run_dir / 'report.html').as_uri(), wait_until='load')
            groups = page.locator('div.samples')
            assert groups.count() == 1
            captions = groups.first.locator('figcaption').all_inner_texts()
            assert captions == ['/camera/image_raw', 'hsv_seg mask']
            sizes = groups.first.locator('img').evaluate_all(
                'imgs => imgs.map(i => [i.naturalWidth, i.naturalHeight])'
            )
            assert sizes == [[SIZE[0], SIZE[1] + 40], [SIZE[0], SIZE[1] + 40]]
            assert errors == []
        finally:
            browser.close()
