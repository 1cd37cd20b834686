"""Report sections for backend agreement and resource use, and the peak-rate page."""

from __future__ import annotations

import json
import re
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.errors import SourceError
from replaybench.report import (
    PEAK_SCHEMA_VERSION,
    load_peak,
    render_peak_report,
    render_report,
)
from replaybench.results import write_json_atomic

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    MakeRun = Callable[..., Path]

HOSTILE = '<script>alert(1)</script>'


def _patch(run_dir: Path, change: Callable[[dict[str, Any]], None]) -> None:
    path = run_dir / 'run.json'
    run = json.loads(path.read_text(encoding='utf-8'))
    change(run)
    write_json_atomic(path, run)


def _titles(text: str) -> list[str]:
    return re.findall(r'<title>(.*?)</title>', text)


def _agreement_entry(a: str, b: str, topic: str, **extra: Any) -> dict[str, Any]:
    entry = {
        'backend_a': a,
        'backend_b': b,
        'topic': topic,
        'frames': 200,
        'n_a': 400,
        'n_b': 380,
        'matched': 361,
        'matched_frac_a': 361 / 400,
        'matched_frac_b': 361 / 380,
        'mean_iou': 0.8123,
        'mean_abs_score_diff': 0.0456,
        'disagreeing_frames': [[0, 17], [0, 3], [0, 44], [0, 5], [0, 6], [0, 7], [0, 8], [0, 9]],
    }
    entry.update(extra)
    return entry


def test_sections_are_absent_without_their_data(make_run: MakeRun) -> None:
    text = render_report(make_run()).read_text(encoding='utf-8')
    assert 'Agreement between backends' not in text
    assert 'Resource use' not in text


def test_agreement_table_per_topic(make_run: MakeRun) -> None:
    run_dir = make_run(topics=('/cam/a', '/cam/b'), backends=('hsv', 'null', 'onnx'))
    entries = [
        _agreement_entry('hsv', 'null', '/cam/a'),
        _agreement_entry('hsv', 'onnx', '/cam/a', matched=0, mean_iou=None, disagreeing_frames=[]),
        _agreement_entry('hsv', 'null', '/cam/b', matched_frac_a=None),
    ]
    _patch(run_dir, lambda run: run.update(agreement=entries))
    text = render_report(run_dir).read_text(encoding='utf-8')
    section = text[
        text.index('id="agreement"') : text.index('</table>', text.index('/cam/b</code></h3>'))
    ]
    assert section.count('<h3><code>') == 2
    assert section.index('/cam/a') < section.index('/cam/b')
    assert '<td class="n">90.2 %</td>' in section  # 361 / 400
    assert '<td class="n">95.0 %</td>' in section  # 361 / 380
    assert '<td class="n">0.812</td>' in section
    assert '<td class="n">0.046</td>' in section
    assert '#17, #3, #44, #5, #6, #7 … (+2)' in section
    assert '>none</td>' in section  # a pair without disagreeing frames
    assert 'IoU ≥ 0.5' in section
    assert section.count('<tr>') == 2 + 1 + 2  # two tables' headers, three rows


def test_agreement_names_are_escaped_and_frames_carry_the_input_with_several_inputs(
    make_run: MakeRun,
) -> None:
    run_dir = make_run(backends=(HOSTILE, 'null'))

    def change(run: dict[str, Any]) -> None:
        run['inputs'].append(dict(run['inputs'][0], index=1))
        run['agreement'] = [
            _agreement_entry(HOSTILE, 'null', HOSTILE, disagreeing_frames=[[1, 4], [0, 2]])
        ]

    _patch(run_dir, change)
    text = render_report(run_dir).read_text(encoding='utf-8')
    assert HOSTILE not in text
    assert '1:#4, 0:#2' in text


def _resources(cpu: float, rss: float, n: int, gpu: bool = False) -> dict[str, Any]:
    series = [
        {
            't_s': 0.1 * i,
            'cpu_percent': cpu + (i % 7),
            'rss_mb': rss + i / n,
            'gpu_util': 55.0 if gpu else None,
            'gpu_mem_mb': 2048.0 if gpu else None,
            'gpu_power_w': 120.0 if gpu else None,
        }
        for i in range(n)
    ]
    summary = {
        'cpu_percent_mean': cpu + 3,
        'cpu_percent_max': cpu + 6,
        'rss_mb_peak': rss + 1,
        'rss_mb_mean': rss + 0.5,
        'gpu_util_mean': 55.0 if gpu else None,
        'gpu_mem_mb_peak': 2048.0 if gpu else None,
        'gpu_power_w_mean': 120.0 if gpu else None,
        'samples': n,
        'interval_s': 0.1,
        'overhead_ms_per_sample': 0.031,
        'overhead_cpu_percent': 0.07,
        'gpu_name': f'GPU {HOSTILE}' if gpu else None,
    }
    return {'summary': summary, 'series': series}


def test_resource_use_table_and_charts(make_run: MakeRun) -> None:
    run_dir = make_run()

    def change(run: dict[str, Any]) -> None:
        run['backends'][0]['resources'] = _resources(97.0, 310.0, 50)
        run['backends'][1]['resources'] = _resources(12.0, 150.0, 40)

    _patch(run_dir, change)
    text = render_report(run_dir).read_text(encoding='utf-8')
    section = text[text.index('id="resources"') :]
    table = section[: section.index('</table>')]
    assert table.count('<tr>') == 3
    for value in ('100.0', '103.0', '311.0', '310.5', '15.0', '18.0', '151.0'):
        assert f'<td class="n">{value}</td>' in table
    assert '0.031 ms/sample, 0.07 % of a core' in table
    assert '50 every 0.1 s' in table
    assert 'GPU' not in table
    titles = _titles(text)
    assert 'CPU use over time' in titles
    assert 'Resident memory over time' in titles
    assert 'GPU utilisation over time' not in titles
    cpu_chart = re.search(r'<svg[^>]*aria-label="CPU use over time".*?</svg>', text, re.S)
    assert cpu_chart is not None
    assert cpu_chart.group(0).count('<polyline') == 2


def test_gpu_columns_and_charts_appear_when_a_backend_has_gpu_readings(
    make_run: MakeRun,
) -> None:
    run_dir = make_run()

    def change(run: dict[str, Any]) -> None:
        run['backends'][0]['resources'] = _resources(97.0, 310.0, 20, gpu=True)
        run['backends'][1]['resources'] = _resources(12.0, 150.0, 20)

    _patch(run_dir, change)
    text = render_report(run_dir).read_text(encoding='utf-8')
    table = text[text.index('id="resources"') :]
    table = table[: table.index('</table>')]
    assert 'GPU util % mean' in table
    assert '<td class="n">55.0</td>' in table
    assert '<td class="n">2048</td>' in table
    assert '<td class="n">120.0</td>' in table
    assert 'GPU utilisation over time' in _titles(text)
    assert 'GPU memory used over time' in _titles(text)
    assert HOSTILE not in text
    assert 'GPU &lt;script&gt;' in text


def test_long_resource_series_keep_the_report_small(make_run: MakeRun) -> None:
    run_dir = make_run(frames=50)
    plain = len(render_report(run_dir).read_bytes())

    def change(run: dict[str, Any]) -> None:
        for entry in run['backends']:
            entry['resources'] = _resources(50.0, 200.0, 2000)

    _patch(run_dir, change)
    grown = len(render_report(run_dir).read_bytes()) - plain
    assert grown < 60_000


# --------------------------------------------------------------------------- peak.html


def _peak(tmp_path: Path, **extra: Any) -> Path:
    trials = [
        (47.6, 54, 0, True, 21.0),
        (95.2, 49, 24, False, 31.4),
        (71.4, 52, 17, False, 34.9),
        (59.5, 53, 10, False, 37.7),
        (53.55, 54, 6, False, 39.6),
        (50.575, 54, 3, False, 40.6),
    ]
    peak: dict[str, Any] = {
        'schema_version': PEAK_SCHEMA_VERSION,
        'kind': 'peak',
        'tool': {'name': 'replaybench', 'version': '0.1.0'},
        'status': 'complete',
        'command': ['replaybench', 'peak', f'/bags/{HOSTILE}.mcap'],
        'started_at': '2025-01-02T03:04:05+00:00',
        'wall_s': 12.5,
        'backend': HOSTILE,
        'input': {'path': f'/bags/{HOSTILE}.mcap', 'sha256': 'ab' * 32},
        'settings': {'max_drop': 0.05, 'p99_bound_ms': 35.0, 'trial_frames': 60, 'min_hz': 1.0},
        'start': {'hz': 47.6, 'from': 'max-rate probe', 'probe_fps': 47.62, 'recorded_hz': 30.0},
        'peak_hz': 47.6,
        'first_failing_hz': 50.575,
        'resolution_hz': 2.975,
        'limit_reached': False,
        'trials': [
            {
                'rate_hz': r,
                'frames': n,
                'dropped': d,
                'drop_fraction': d / n,
                'p99_ms': p,
                'ok': ok,
                'run_dir': f'trials/{r:.3f}hz',
            }
            for r, n, d, ok, p in trials
        ],
        'environment': {'cpu': {'model': 'CPU'}, 'gpus': []},
    }
    peak.update(extra)
    out = tmp_path / 'peak'
    out.mkdir(exist_ok=True)
    write_json_atomic(out / 'peak.json', peak)
    return out


def test_peak_page_shows_the_trials_the_charts_and_the_found_peak(tmp_path: Path) -> None:
    path = render_peak_report(_peak(tmp_path))
    assert path.name == 'peak.html'
    text = path.read_text(encoding='utf-8')
    assert 'Peak sustainable rate: 47.6 Hz' in text
    assert 'The lowest failing rate tested was 50.575 Hz (resolution 2.98 Hz)' in text
    rows = re.findall(r'<tr[ >].*?</tr>', text[text.index('id="trials"') :], re.S)
    assert len(rows) == 1 + 6
    assert rows[1].startswith('<tr class="peak">')
    assert '<td class="n">11.1 %</td>' in rows[5]  # 6 / 54
    assert 'trials/53.550hz' in rows[5]
    assert text.count('>pass</span>') == 1
    assert text.count('>fail</span>') == 5
    titles = _titles(text)
    assert 'Dropped frames vs rate' in titles
    assert 'p99 latency vs rate' in titles
    assert text.count('>peak 47.6 Hz</text>') == 2
    assert '>max 5 %</text>' in text
    assert '>bound 35 ms</text>' in text
    assert HOSTILE not in text
    assert '<script' not in text
    assert 'http://' not in text


def test_peak_page_says_when_no_rate_passed_or_the_sweep_was_interrupted(tmp_path: Path) -> None:
    out = _peak(tmp_path, peak_hz=None, status='interrupted', first_failing_hz=1.0)
    text = render_peak_report(out).read_text(encoding='utf-8')
    assert 'No tested rate passed' in text
    assert 'The sweep was interrupted' in text
    assert 'class="peak"' not in text
    assert '>peak ' not in text


def test_peak_page_notes_a_search_that_reached_its_limit(tmp_path: Path) -> None:
    out = _peak(tmp_path, limit_reached=True, first_failing_hz=None)
    text = render_peak_report(out).read_text(encoding='utf-8')
    assert 'may keep up with more' in text


@pytest.mark.parametrize(
    ('extra', 'message'),
    [
        ({'schema_version': PEAK_SCHEMA_VERSION + 1}, 'newer'),
        ({'schema_version': 'one'}, 'schema_version'),
        ({'kind': 'run'}, 'not a peak.json'),
    ],
)
def test_load_peak_refuses_what_it_cannot_read(
    tmp_path: Path, extra: dict[str, Any], message: str
) -> None:
    with pytest.raises(SourceError, match=message):
        load_peak(_peak(tmp_path, **extra))


def test_load_peak_without_peak_json_says_so(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match=r'no peak\.json'):
        load_peak(tmp_path)
    (tmp_path / 'peak.json').write_text('{', encoding='utf-8')
    with pytest.raises(SourceError, match='invalid JSON'):
        load_peak(tmp_path)
