"""report.html of a stereo run: each backend's disparity of the sample pair, colour-mapped, with
its error against truth beside it, under the pair's frame (checked in headless Chromium)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

import replaybench as rb
from replaybench.decode import decode_image
from replaybench.fixtures.stereo import write_stereo_mcap
from replaybench.sources import open_source
from replaybench.stereo import Matcher
from replaybench.stereo.thumbnail import disparity_picture, error_picture

Image = np.ndarray[Any, Any]
CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--no-first-run']
FRAMES = 3
SIZE = (320, 240)
FRAME_REL = 'samples/input0_stereo_left_image_rect.jpg'
SGBM_REL = 'samples/input0_stereo_left_image_rect.disparity_sgbm.png'
BM_REL = 'samples/input0_stereo_left_image_rect.disparity_bm.png'


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_stereo_mcap(tmp_path_factory.mktemp('bag') / 'stereo.mcap', FRAMES, SIZE)


@pytest.fixture(scope='module')
def run_dir(bag: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp('runs') / 'run'
    rb.run(bag, backends=['sgbm', 'bm'], out=out)
    return out


def _sample_pair(bag: Path) -> tuple[Image, Image, Image]:
    """The middle pair (the sample) and its truth."""
    found: dict[str, list[Image]] = {}
    with open_source(bag) as source:
        for raw in source.messages():
            if raw.msgtype == 'sensor_msgs/msg/Image':
                found.setdefault(raw.topic, []).append(np.asarray(decode_image(raw).image))
    middle = FRAMES // 2
    return (
        found['/stereo/left/image_rect'][middle],
        found['/stereo/right/image_rect'][middle],
        found['/ground_truth/disparity'][middle],
    )


def test_the_disparity_thumbnail_is_the_colour_mapped_disparity_and_its_error_beside_it(
    bag: Path, run_dir: Path
) -> None:
    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    assert document['outputs']['samples'] == [FRAME_REL, SGBM_REL, BM_REL]
    left, right, truth = _sample_pair(bag)
    d = Matcher('sgbm').compute(left, right)
    expected = np.concatenate(
        [
            disparity_picture(d, max_disparity=63, width=320),
            np.full((SIZE[1], 4, 3), 255, np.uint8),
            error_picture(d, truth, width=320),
        ],
        axis=1,
    )
    thumb = cv2.imread(str(run_dir / SGBM_REL), cv2.IMREAD_COLOR)
    assert thumb is not None
    # the thumbnail is scaled to the samples' width: compare at the written scale
    body = thumb[20 : thumb.shape[0] - 20]
    size = (body.shape[1], body.shape[0])
    scaled = cv2.resize(expected[:, :, ::-1], size, interpolation=cv2.INTER_AREA)
    assert np.mean(np.abs(body.astype(int) - scaled.astype(int))) < 3.0
    # the error half is mostly green (within 1 px) with some magenta (truth, no estimate)
    error = expected[:, 324:]
    green = np.all(error == (40, 180, 60), axis=-1).mean()
    assert 0.3 < green < 0.95
    html = (run_dir / 'report.html').read_text(encoding='utf-8')
    (group,) = re.findall(r'<div class="samples">(.*?)</div>', html)
    assert re.findall(r'<figcaption>(.*?)</figcaption>', group) == [
        '/stereo/left/image_rect',
        'sgbm disparity',
        'bm disparity',
    ]


def test_without_truth_the_thumbnail_shows_the_disparity_alone(bag: Path, tmp_path: Path) -> None:
    empty = tmp_path / 'gt'
    empty.mkdir()
    (empty / '1.pfm').write_bytes(b'Pf\n1 1\n-1\n' + np.float32(1.0).tobytes())  # no pair's stamp
    out = tmp_path / 'run'
    rb.run(bag, backends=['sgbm'], out=out, ground_truth_disparity=str(empty))
    thumb = cv2.imread(str(out / SGBM_REL), cv2.IMREAD_COLOR)
    assert thumb is not None
    assert thumb.shape[1] == SIZE[0]  # one half: no error picture


def test_the_report_shows_the_disparities_beside_their_frame_in_a_browser(run_dir: Path) -> None:
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
            group = page.locator('div.samples').first
            captions = group.locator('figcaption').all_inner_texts()
            assert captions == ['/stereo/left/image_rect', 'sgbm disparity', 'bm disparity']
            loaded = group.locator('img').evaluate_all(
                'imgs => imgs.map(i => i.complete && i.naturalWidth > 0)'
            )
            assert loaded == [True, True, True]
            assert errors == []
        finally:
            browser.close()
