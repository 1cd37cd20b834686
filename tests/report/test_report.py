"""report.html from a run folder: content, self-containment, escaping and size."""

from __future__ import annotations

import base64
import json
import re
from typing import TYPE_CHECKING

import pytest

from replaybench.errors import SourceError
from replaybench.report import render_report
from replaybench.results import load_run

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    MakeRun = Callable[..., Path]

HOSTILE = '<script>alert(1)</script>'  # the topic/backend/path name conftest.make_run uses


def _svgs(text: str) -> list[str]:
    return re.findall(r'<svg\b.*?</svg>', text, flags=re.S)


def test_report_shows_the_summary_numbers_and_the_charts(make_run: MakeRun) -> None:
    run_dir = make_run(topics=('/cam/a', '/cam/b'), backends=('hsv', 'null', 'onnx'))
    path = render_report(run_dir)
    assert path == run_dir / 'report.html'
    text = path.read_text(encoding='utf-8')
    run = load_run(run_dir).run
    for row in run.summary_rows:
        assert f'<td class="n">{row.latency_ms_p50:.2f}</td>' in text
        assert f'<td class="n">{row.throughput_fps:.1f}</td>' in text
    svgs = _svgs(text)
    # per topic: latency over time, CDF, detections; plus throughput and stage bars
    assert len(svgs) == 2 * 3 + 2
    titles = re.findall(r'<title>(.*?)</title>', text)
    assert 'Latency over time · /cam/a' in titles
    assert 'Latency CDF · /cam/b (measured frames)' in titles
    assert 'Throughput (measured frames per second)' in titles
    assert 'Mean latency by stage (measured frames)' in titles
    assert 'Detections per frame · /cam/a' in titles
    for backend in ('hsv', 'null', 'onnx'):
        assert f'>{backend}</text>' in svgs[0]
    assert '0123456789ab' in text
    assert 'AP@0.5' not in text


def test_report_is_one_file_with_no_external_resources(make_run: MakeRun) -> None:
    text = render_report(make_run(samples=True)).read_text(encoding='utf-8')
    assert '<script' not in text
    assert '<link' not in text
    assert '@import' not in text
    assert not re.search(r'(src|href)\s*=\s*["\']?\s*(https?:)?//', text)
    assert not re.search(r'url\(\s*["\']?(https?:)?//', text)
    assert 'http://' not in text
    assert 'https://' not in text


def test_hostile_names_are_escaped_everywhere(make_run: MakeRun) -> None:
    run_dir = make_run(
        topics=(HOSTILE, '/cam/ok'),
        samples=True,
        accuracy=True,
        truncated=True,
        skip_every=50,
    )
    text = render_report(run_dir).read_text(encoding='utf-8')
    assert HOSTILE not in text
    assert '<script' not in text
    assert '&lt;script&gt;alert(1)&lt;/script&gt;' in text
    for svg in _svgs(text):
        assert '<script' not in svg


def test_warnings_banner_for_interrupted_truncated_and_skipped(make_run: MakeRun) -> None:
    text = render_report(
        make_run(status='interrupted', truncated=True, skip_every=40),
    ).read_text(encoding='utf-8')
    banner = re.search(r'<div class="banner".*?</div>', text, flags=re.S)
    assert banner is not None
    assert 'interrupted' in banner.group(0)
    assert 'truncated' in banner.group(0)
    assert '10 frame(s) were skipped' in banner.group(0)  # 5 per backend x 2 backends


def test_a_clean_complete_run_has_no_banner(make_run: MakeRun) -> None:
    text = render_report(make_run()).read_text(encoding='utf-8')
    assert 'class="banner"' not in text


def test_accuracy_columns_appear_when_a_backend_was_scored(make_run: MakeRun) -> None:
    text = render_report(make_run(accuracy=True)).read_text(encoding='utf-8')
    assert 'mAP@0.5:0.95' in text
    assert '<td class="n">0.543</td>' in text
    assert '<td class="n">0.875</td>' in text
    assert 'Average precision per class' in text


def test_samples_are_embedded_as_data_uris(make_run: MakeRun) -> None:
    run_dir = make_run(samples=True, topics=('/cam/a', '/cam/b'))
    text = render_report(run_dir).read_text(encoding='utf-8')
    uris = re.findall(r'src="data:image/jpeg;base64,([A-Za-z0-9+/=]+)"', text)
    assert len(uris) == 2
    on_disk = (run_dir / 'samples' / 'input0_cam_a.jpg').read_bytes()
    assert base64.b64decode(uris[0]) == on_disk
    assert '<h3><code>/cam/a</code></h3>' in text


def test_samples_outside_the_run_folder_are_not_embedded(make_run: MakeRun) -> None:
    run_dir = make_run(samples=True)
    secret = run_dir.parent / 'secret.png'
    secret.write_bytes(b'\x89PNG secret')
    run = json.loads((run_dir / 'run.json').read_text())
    run['outputs']['samples'] = ['../secret.png', str(secret), 'samples/missing.jpg']
    (run_dir / 'run.json').write_text(json.dumps(run))
    text = render_report(run_dir).read_text(encoding='utf-8')
    assert 'data:image' not in text
    assert base64.b64encode(b'\x89PNG secret').decode() not in text
    assert text.count('is missing or not an image in the run folder') == 3


def test_report_for_5000_frames_stays_small(make_run: MakeRun) -> None:
    run_dir = make_run(frames=5000, backends=('hsv', 'null', 'onnx'), drop_every=37)
    size = render_report(run_dir).stat().st_size
    assert size < 1_000_000


def test_rendering_twice_gives_the_same_bytes(make_run: MakeRun) -> None:
    run_dir = make_run(samples=True, drop_every=10)
    first = render_report(run_dir).read_bytes()
    assert render_report(run_dir).read_bytes() == first
    assert sorted(p.name for p in run_dir.iterdir()) == [
        'frames.csv',
        'report.html',
        'run.json',
        'samples',
    ]


def test_a_run_json_without_summary_is_summarised_from_frames(make_run: MakeRun) -> None:
    run_dir = make_run()
    run = json.loads((run_dir / 'run.json').read_text())
    expected = run.pop('summary')
    (run_dir / 'run.json').write_text(json.dumps(run))
    text = render_report(run_dir).read_text(encoding='utf-8')
    for row in expected:
        assert f'<td class="n">{row["latency_ms_p95"]:.2f}</td>' in text


def test_dropped_frames_are_marked_on_the_latency_chart(make_run: MakeRun) -> None:
    text = render_report(make_run(drop_every=20, frames=200)).read_text(encoding='utf-8')
    latency_chart = _svgs(text)[0]
    assert 'hsv dropped (10)' in latency_chart
    assert 'warm-up' in latency_chart


def test_a_folder_without_run_json_cannot_be_rendered(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r'no run\.json'):
        render_report(tmp_path)


def test_every_chart_over_time_of_a_two_frame_run_says_in_words_it_has_too_few_points(
    make_run: MakeRun,
) -> None:
    text = render_report(make_run(frames=2)).read_text(encoding='utf-8')
    over_time = [s for s in _svgs(text) if ' over time' in s or 'Detections per frame' in s]
    assert len(over_time) == 2  # latency and detections; the run sampled no resources
    for svg in over_time:
        assert 'Too few points to show a trend: fewer than 3 per series.' in svg
        assert '<circle' not in svg
        assert '<polyline' not in svg
    assert '>hsv: 2 points: ' in over_time[0]


def test_cpu_use_of_one_sample_is_said_in_words_not_drawn_as_a_dot_on_an_empty_axis(
    make_run: MakeRun,
) -> None:
    from dataclasses import replace

    from replaybench.results.io import read_run_result, write_run_result
    from replaybench.results.model import ResourcePoint, Resources, ResourceSummary

    run_dir = make_run()
    run = read_run_result(run_dir / 'run.json')
    point = ResourcePoint(t_s=0.05, cpu_percent=190.0, private_mb=30.0)
    summary = ResourceSummary(
        samples=1, interval_s=0.05, duration_s=0.05, cpu_source='process_time'
    )
    backends = tuple(
        replace(b, resources=Resources(summary=summary, series=(point,))) for b in run.backends
    )
    write_run_result(run_dir / 'run.json', replace(run, backends=backends))
    text = render_report(run_dir).read_text(encoding='utf-8')
    [cpu] = [s for s in _svgs(text) if 'aria-label="CPU use over time"' in s]
    assert 'Too few points to show a trend: fewer than 3 per series.' in cpu
    assert '>hsv: 1 point: 190 at 0.05</text>' in cpu
    assert '<circle' not in cpu
    assert '-0.4' not in cpu
