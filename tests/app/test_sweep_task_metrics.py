"""A task registered through the ``replaybench.tasks`` entry points, with a metric the sweep
shows, gets that metric in a sweep with no edit to a shared file: a column of sweep.csv and a key
of sweep.json's cells (empty where no backend has it), sweep.html's figure and the terminal
table's column where a cell has a value; an older sweep.json without it still reads."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.tasks import ENTRY_POINT_GROUP, MetricSpec

if TYPE_CHECKING:
    from collections.abc import Iterator

REPO = Path(__file__).resolve().parents[2]
SCHEMA = REPO / 'replaybench' / 'schemas' / 'sweep.schema.json'
BAG = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
MODULE = 'rb_sweep_toy_task'

PLUGIN = """
from replaybench.tasks import MetricSpec


class ToyTask:
    name = 'toy'
    metrics = (
        MetricSpec(
            'toy_score', 'toy score', 'toy', 'higher', sweep=True, main=True, terminal_label='toy'
        ),
    )
    recorded_readers: dict[str, object] = {}


TASK = ToyTask()
"""


@pytest.fixture(scope='module')
def toy_ray(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """The toy task in an installed distribution's entry points (a real module and dist-info
    folder on sys.path and on PYTHONPATH, so that Ray's workers find it too), then a local Ray
    instance as `replaybench sweep` starts one; both gone after the module."""
    pytest.importorskip('ray', reason='the sweep extra (Ray) is not installed')
    from replaybench.app.sweep import local_ray

    site = tmp_path_factory.mktemp('site')
    (site / f'{MODULE}.py').write_text(PLUGIN, encoding='utf-8')
    dist = site / 'rb_sweep_toy-0.1.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text(
        'Metadata-Version: 2.1\nName: rb-sweep-toy\nVersion: 0.1\n', encoding='utf-8'
    )
    (dist / 'entry_points.txt').write_text(
        f'[{ENTRY_POINT_GROUP}]\ntoy = {MODULE}:TASK\n', encoding='utf-8'
    )
    old_path, old_env = list(sys.path), os.environ.get('PYTHONPATH')
    sys.path.insert(0, str(site))
    os.environ['PYTHONPATH'] = os.pathsep.join(p for p in (str(site), old_env) if p)
    temp = tempfile.mkdtemp(prefix='rb-ray-')  # short: Ray's socket paths must stay < 108 chars
    try:
        with local_ray(num_cpus=2, temp_dir=temp):
            yield site
    finally:
        shutil.rmtree(temp, ignore_errors=True)
        sys.path[:] = old_path
        if old_env is None:
            os.environ.pop('PYTHONPATH', None)
        else:
            os.environ['PYTHONPATH'] = old_env
        sys.modules.pop(MODULE, None)


@pytest.mark.usefixtures('toy_ray')
def test_a_task_from_an_entry_point_has_its_sweep_metric_in_sweep_csv_and_json(
    tmp_path: Path,
) -> None:
    import jsonschema

    from replaybench.app.sweep import sweep
    from replaybench.app.sweep.record import csv_columns, sweep_metrics
    from replaybench.app.sweep.terminal import result_lines
    from replaybench.report.sweep_html import render_sweep_html
    from replaybench.results.sweepfile import read_sweep_result

    # after the built-in tasks' sweep metrics, before their streaming ones (docs/streaming.md)
    assert [m.name for m in sweep_metrics()][-2:] == ['toy_score', 'streaming_map50']
    out = tmp_path / 'sw'
    result = sweep(
        [BAG],
        out=out,
        backends=['null', 'hsv'],
        max_frames=12,
        warmup=0,
        report=False,
        command=['replaybench', 'sweep'],
    )
    assert result.status == 'complete'

    with (out / 'sweep.csv').open(newline='', encoding='utf-8') as f:
        header, *rows = list(csv.reader(f))
    assert tuple(header) == csv_columns()
    assert header.index('toy_score') == header.index('mota') + 1  # after the built-in tasks'
    assert len(rows) == 2
    # no backend has the toy task: its cell is empty, as another task's is
    assert [r[header.index('toy_score')] for r in rows] == ['', '']
    assert [r[header.index('map50')] != '' for r in rows] == [True, True]

    document = json.loads((out / 'sweep.json').read_text(encoding='utf-8'))
    schema = json.loads(SCHEMA.read_text(encoding='utf-8'))
    jsonschema.Draft202012Validator(schema).validate(document)
    metrics = [c['metrics'] for c in document['cells']]
    assert all(list(m)[-2] == 'toy_score' and m['toy_score'] is None for m in metrics)
    record = read_sweep_result(out)
    assert record == result.sweep
    assert all(c.metrics is not None and 'toy_score' in c.metrics.values for c in record.cells)

    # without a value the toy's figure is not shown; where a cell has one, it is
    html = (out / 'sweep.html').read_text(encoding='utf-8')
    assert 'toy score' not in html
    lines, _ = result_lines(result)
    assert 'toy' not in lines[0].split()
    scored = [dict(m, toy_score=value) for m, value in zip(metrics, (0.25, 0.75), strict=True)]
    cells = [dict(c, metrics=m) for c, m in zip(document['cells'], scored, strict=True)]
    html = render_sweep_html({**document, 'cells': cells})
    assert 'toy score 0.250 · ' in html
    assert 'toy score 0.750 · ' in html
    assert html.count('best toy score') == 1
    held = tuple(
        dataclasses.replace(
            c,
            metrics=dataclasses.replace(c.metrics, values={**c.metrics.values, 'toy_score': v}),
        )
        for c, v in zip(record.cells, (0.25, 0.75), strict=True)
        if c.metrics is not None
    )
    shown = dataclasses.replace(result, sweep=dataclasses.replace(record, cells=held))
    lines, _ = result_lines(shown)
    assert lines[0].split()[-2:] == ['toy', 'node']
    assert [line.split()[-2] for line in lines[1:3]] == ['0.250', '0.750']


def test_a_metric_value_is_the_rows_field_else_its_entry_in_the_rows_task_metrics() -> None:
    from replaybench.app.sweep.record import metric_value
    from replaybench.results.model import SummaryRow

    toy = MetricSpec('toy_score', 'toy score', 'toy', 'higher', sweep=True)
    miou = MetricSpec('miou', 'mIoU', 'mIoU', 'higher', sweep=True)
    assert metric_value(SummaryRow(task_metrics={'toy_score': 1}), toy) == 1.0
    assert metric_value(SummaryRow(task_metrics={}), toy) is None
    assert metric_value(SummaryRow(task_metrics={'toy_score': float('nan')}), toy) is None
    assert metric_value(SummaryRow(miou=0.25), miou) == 0.25
    assert metric_value(SummaryRow(miou=0.25, task_metrics={'miou': 0.5}), miou) == 0.25
    assert metric_value(SummaryRow(), miou) is None
    assert metric_value(SummaryRow(), toy) is None  # no field and no mapping of it


def test_a_sweep_json_without_the_later_metric_keys_still_reads(tmp_path: Path) -> None:
    from replaybench.app.sweep.record import csv_row
    from replaybench.results.sweepfile import read_sweep_result, sweep_document

    cell: dict[str, Any] = {
        'index': 0,
        'cell': 'a.hsv-0123456789',
        'input': 'a.mcap',
        'backend': 'hsv',
        'status': 'complete',
        'metrics': {
            'frames': 9,
            'fps': 100.0,
            'fps_ci': None,
            'p50_ms': 1.0,
            'p50_ci': None,
            'p99_ms': 2.0,
            'p99_ci': None,
            'map50': 0.5,
            'topics': 1,
        },
    }
    (tmp_path / 'sweep.json').write_text(
        json.dumps({'schema_version': 1, 'status': 'complete', 'cells': [cell]}), encoding='utf-8'
    )
    record = read_sweep_result(tmp_path)
    (read,) = record.cells
    assert read.metrics is not None
    assert read.metrics.values == {'map50': 0.5}
    assert read.metrics.map50 == 0.5
    assert read.metrics.value('miou') is None
    row = csv_row(read)
    assert (row['map50'], row['miou'], row['tag_recall'], row['frames']) == (0.5, None, None, 9)
    # written again, the keys it held keep their places
    assert list(sweep_document(record)['cells'][0]['metrics']) == list(cell['metrics'])
