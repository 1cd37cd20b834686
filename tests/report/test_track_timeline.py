"""report.html's Tracking section: the id-switch timeline of each tracked row, from a real run
over the tracking fixture (``replaybench run tracks.mcap --backend hsv --tracker iou --tracker
bytetrack``), its ticks counted against summary.csv, drawn again from the run folder, and
shown in Chromium (skipped locally without the browser, as test_browser.py)."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import replaybench as rb
from replaybench.fixtures.tracks import write_tracks_mcap
from replaybench.report.tracks import MAX_LANES, timeline_svg, track_timelines_html
from replaybench.results.model import IdSwitchEvent, TrackLane, TrackSpan, TrackTimeline

CHROMIUM = Path('/usr/bin/chromium')
CHROMIUM_ARGS = ['--no-sandbox', '--disable-gpu', '--no-first-run', '--disable-quic']
TRACKED = ('hsv+iou', 'hsv+bytetrack')
TRACKERS = ('--tracker', 'iou', '--tracker', 'bytetrack')


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *args], capture_output=True, text=True, check=False
    )


@pytest.fixture(scope='module')
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp('timeline')
    bag = write_tracks_mcap(base / 'tracks.mcap')
    out = base / 'run'
    done = _cli('run', str(bag), '--backend', 'hsv', *TRACKERS, '--out', str(out))
    assert done.returncode == 0, done.stderr
    return out


def _svgs(html: str) -> dict[str, str]:
    """Each timeline's SVG markup by its row's backend."""
    found = re.findall(r'(<svg class="chart track-timeline" data-backend="([^"]*)".*?</svg>)', html)
    return {backend: svg for svg, backend in found}


def _switches(run_dir: Path) -> dict[str, int]:
    with (run_dir / 'summary.csv').open(newline='', encoding='utf-8') as f:
        return {
            r['backend']: int(float(r['id_switches']))
            for r in csv.DictReader(f)
            if r['id_switches']
        }


def test_each_tracked_row_has_a_timeline_with_a_tick_per_id_switch_of_summary_csv(
    run_dir: Path,
) -> None:
    html = (run_dir / 'report.html').read_text(encoding='utf-8')
    assert '<h2 id="tracking">Tracking</h2>' in html
    svgs = _svgs(html)
    switches = _switches(run_dir)
    assert sorted(svgs) == sorted(TRACKED) == sorted(switches)  # hsv alone has no tracks
    assert switches['hsv+iou'] > 0  # the crossings make the IoU-only tracker switch
    for backend in TRACKED:
        svg = svgs[backend]
        assert svg.count('<g class="idsw">') == switches[backend]
        noun = 'switch' if switches[backend] == 1 else 'switches'
        assert f'>{switches[backend]} ID {noun} (id_switches in summary.csv)<' in svg
        assert 'href' not in svg  # self-contained: nothing linked or loaded
        # one lane per truth object of the fixture, in id order
        assert re.findall(r'>object (\w+)</text>', svg) == ['1', '2', '3', '4', '5', '6']


def test_the_ticks_name_the_switches_of_run_json_and_the_lanes_show_the_matched_tracks(
    run_dir: Path,
) -> None:
    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    rows = {r['backend']: r for r in document['summary']}
    assert 'track_timeline' not in rows['hsv']
    svgs = _svgs((run_dir / 'report.html').read_text(encoding='utf-8'))
    for backend in TRACKED:
        timeline = rows[backend]['track_timeline']
        assert len(timeline['switches']) == rows[backend]['task_metrics']['id_switches']
        # each frame of the sequence named by its frames.csv seq too
        seqs = timeline['seqs']
        assert len(seqs) == timeline['frames']
        assert seqs == sorted(set(seqs))
        with (run_dir / 'frames.csv').open(newline='', encoding='utf-8') as f:
            ok = {int(r['seq']) for r in csv.DictReader(f) if r['backend'] == backend}
        assert set(seqs) <= ok
        tips = re.findall(r'<g class="idsw"><title>([^<]*)</title>', svgs[backend])
        assert tips == [
            f'frame {s["frame"]} (seq {seqs[s["frame"]]}): object {s["object_id"]}, '
            f'track {s["from_id"]} → {s["to_id"]}'
            for s in timeline['switches']
        ]
        # each switch is where its object's matched track changes from one span to another
        for s in timeline['switches']:
            (lane,) = [lane for lane in timeline['lanes'] if lane['object_id'] == s['object_id']]
            matched = [span for span in lane['spans'] if span['track_id'] is not None]
            (now,) = [span for span in matched if span['first'] == s['frame']]
            before = [span for span in matched if span['last'] < s['frame']][-1]
            assert (before['track_id'], now['track_id']) == (s['from_id'], s['to_id'])
        matched_bars = re.findall(r'<rect class="matched"', svgs[backend])
        spans = [sp for lane in timeline['lanes'] for sp in lane['spans']]
        assert len(matched_bars) == sum(1 for sp in spans if sp['track_id'] is not None)


def test_replaybench_report_draws_the_same_timelines_from_the_run_folder(
    run_dir: Path, tmp_path: Path
) -> None:
    again = tmp_path / 'again'
    again.mkdir()
    for name in ('run.json', 'frames.csv', 'summary.csv'):
        (again / name).write_bytes((run_dir / name).read_bytes())
    done = _cli('report', str(again))
    assert done.returncode == 0, done.stderr
    first = _svgs((run_dir / 'report.html').read_text(encoding='utf-8'))
    assert _svgs((again / 'report.html').read_text(encoding='utf-8')) == first
    loaded = rb.load_run(again).summary_rows
    timelines = {r.backend: r.track_timeline for r in loaded}
    assert timelines['hsv'] is None
    iou = timelines['hsv+iou']
    assert iou is not None
    assert len(iou.switches) == _switches(run_dir)['hsv+iou']


def test_a_run_json_without_timelines_says_so_in_one_line_per_tracked_row(
    run_dir: Path, tmp_path: Path
) -> None:
    older = tmp_path / 'older'
    older.mkdir()
    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    for row in document['summary']:
        row.pop('track_timeline', None)
    (older / 'run.json').write_text(json.dumps(document), encoding='utf-8')
    (older / 'frames.csv').write_bytes((run_dir / 'frames.csv').read_bytes())
    done = _cli('report', str(older))
    assert done.returncode == 0, done.stderr
    html = (older / 'report.html').read_text(encoding='utf-8')
    assert _svgs(html) == {}
    switches = _switches(run_dir)
    for backend in TRACKED:
        assert (
            f'{backend} · <code>/camera/image_raw/compressed</code>: {switches[backend]} ID '
            'switches; no timeline' in html
        )


def test_recorded_tracks_have_their_timeline_too(tmp_path: Path) -> None:
    live = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'live_tracks.mcap'
    out = tmp_path / 'live'
    done = _cli('run', str(live), '--backend', 'recorded', '--out', str(out))
    assert done.returncode == 0, done.stderr
    (row,) = rb.load_run(out).summary_rows
    assert row.track_timeline is not None
    assert len(row.track_timeline.switches) == row.metric('id_switches')
    svg = _svgs((out / 'report.html').read_text(encoding='utf-8'))['recorded']
    assert svg.count('<g class="idsw">') == row.metric('id_switches')
    objects = [lane.object_id for lane in row.track_timeline.lanes]
    assert re.findall(r'>object (\w+)</text>', svg) == objects
    assert len(objects) > 1


def _many_lanes(objects: int) -> TrackTimeline:
    """``objects`` objects over 10 frames; object i switches i % 4 times."""
    lanes, switches = [], []
    for i in range(objects):
        spans = [TrackSpan(0, 1, f'{i}-0')]
        for k in range(i % 4):
            spans.append(TrackSpan(2 + 2 * k, 3 + 2 * k, f'{i}-{k + 1}'))
            switches.append(IdSwitchEvent(2 + 2 * k, str(i), f'{i}-{k}', f'{i}-{k + 1}'))
        lanes.append(TrackLane(str(i), tuple(spans)))
    switches.sort(key=lambda s: s.frame)
    return TrackTimeline(frames=10, lanes=tuple(lanes), switches=tuple(switches))


def test_at_most_forty_lanes_are_drawn_those_with_the_most_switches_the_rest_counted() -> None:
    timeline = _many_lanes(50)
    svg = timeline_svg('hsv+sort', '/cam', timeline)
    shown = re.findall(r'>object (\d+)</text>', svg)
    assert len(shown) == MAX_LANES == 40
    assert shown == sorted(shown, key=int)  # in id order
    # the 10 left out are ten of the 13 objects without a switch (i % 4 == 0)
    left_out = set(range(50)) - {int(s) for s in shown}
    assert all(i % 4 == 0 for i in left_out)
    assert svg.count('<g class="idsw">') == len(timeline.switches)  # none of them hidden
    assert '>' + f'{len(timeline.switches)} ID switches (id_switches in summary.csv)<' in svg

    from replaybench.results.model import SummaryRow

    html = track_timelines_html(
        [SummaryRow(backend='hsv+sort', topic='/cam', track_timeline=timeline)]
    )
    assert '10 of 50 objects not shown (the 40 with the most ID switches are); 0 of the ID' in html


def test_a_timeline_escapes_the_ids_it_shows() -> None:
    timeline = TrackTimeline(
        frames=2,
        lanes=(TrackLane('<b>', (TrackSpan(0, 0, '"x"'), TrackSpan(1, 1, '&'))),),
        switches=(IdSwitchEvent(1, '<b>', '"x"', '&'),),
    )
    svg = timeline_svg('a<b', '/t', timeline)
    assert '<b>' not in svg
    assert 'object &lt;b&gt;, track &quot;x&quot; → &amp;' in svg


def _require_browser() -> None:
    import os

    missing = []
    if not CHROMIUM.is_file():
        missing.append(f'{CHROMIUM} is missing (apt-get install -y chromium)')
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing.append('the playwright package is missing (pip install playwright)')
    if missing:
        if os.environ.get('CI', '').strip().lower() not in ('', '0', 'false', 'no'):
            pytest.fail(f'browser test cannot run in CI: {"; ".join(missing)}', pytrace=False)
        pytest.skip(f'browser test needs a browser: {"; ".join(missing)}')


def test_chromium_draws_the_timelines_with_their_ticks_visible_inside_them(run_dir: Path) -> None:
    _require_browser()
    from playwright.sync_api import sync_playwright

    switches = _switches(run_dir)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={'width': 1366, 'height': 900})
            errors: list[str] = []
            requests: list[str] = []
            page.on('pageerror', lambda e: errors.append(str(e)))
            page.on('request', lambda r: requests.append(r.url))
            page.goto((run_dir / 'report.html').as_uri(), wait_until='load')
            charts = page.locator('svg.track-timeline')
            assert charts.count() == len(TRACKED)
            for i in range(charts.count()):
                chart = charts.nth(i)
                chart.scroll_into_view_if_needed()
                backend = chart.get_attribute('data-backend')
                assert backend in TRACKED
                box = chart.bounding_box()
                assert box is not None
                assert box['width'] > 600
                ticks = chart.locator('g.idsw')
                assert (
                    ticks.count()
                    == switches[backend]
                    == int(chart.get_attribute('data-switches') or -1)
                )
                for k in range(ticks.count()):
                    tick = ticks.nth(k)
                    assert tick.is_visible()
                    t = tick.bounding_box()
                    assert t is not None
                    assert t['width'] > 0
                    assert t['height'] > 0
                    assert box['x'] <= t['x'] <= box['x'] + box['width']
                    assert box['y'] <= t['y'] <= box['y'] + box['height']
                # the bars are drawn: their colours are the track palette's, not the default
                fills = chart.locator('rect.matched').evaluate_all(
                    'rs => rs.map(r => getComputedStyle(r).fill)'
                )
                assert fills
                assert 'rgb(0, 0, 0)' not in fills
            assert errors == []
            assert requests == [(run_dir / 'report.html').as_uri()]
        finally:
            browser.close()
