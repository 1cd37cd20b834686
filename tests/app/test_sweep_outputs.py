"""The sweep folder on one local Ray instance: sweep.json through its typed model, a finished
cell read back from no file, sweep.csv grown by appending, and the run options the sweep lacked
(--format, --no-hash, --ground-truth-file/-match/-image-topic/-seq-offset, --device) in a cell."""

from __future__ import annotations

import csv
import itertools
import json
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.app.sweep import SweepResult

pytestmark = pytest.mark.usefixtures('ray_local')


def _sweep(inputs: list[Path], out: Path, **options: Any) -> SweepResult:
    from replaybench.app.sweep import sweep

    options.setdefault('max_frames', 12)
    options.setdefault('report', False)
    return sweep(inputs, out=out, command=['replaybench', 'sweep'], **options)


def test_sweep_json_is_written_and_read_through_its_typed_model(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    from replaybench.results.sweepfile import (
        CellMetrics,
        SweepRecord,
        read_sweep_result,
        sweep_document,
    )

    result = _sweep([bags['a']], tmp_path / 'sw', backends=['null', 'hsv'])
    assert result.status == 'complete'
    record = read_sweep_result(tmp_path / 'sw')
    assert isinstance(record, SweepRecord)
    assert record == result.sweep
    assert all(isinstance(c.metrics, CellMetrics) for c in record.cells)
    assert record.settings.backends == ('null', 'hsv')
    assert record.settings.options['max_frames'] == 12
    text = json.loads((tmp_path / 'sw' / 'sweep.json').read_text(encoding='utf-8'))
    assert sweep_document(record) == text
    assert text['settings']['max_frames'] == 12  # the run options stay keys of settings
    assert text['settings']['rate'] == 'max'


def test_a_finished_cell_is_read_back_from_no_file_and_a_resume_reads_each_run_json_once(
    bags: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import replaybench.results.io as results_io
    import replaybench.results.records as records

    reads: list[str] = []
    real_run, real_frames = results_io.read_run_result, records.read_frames_csv

    def read_run(path: Any) -> Any:
        reads.append(f'run.json {path}')
        return real_run(path)

    def read_frames(path: Any) -> Any:
        reads.append(f'frames.csv {path}')
        return real_frames(path)

    monkeypatch.setattr(results_io, 'read_run_result', read_run)
    monkeypatch.setattr(records, 'read_frames_csv', read_frames)
    out = tmp_path / 'sw'
    first = _sweep([bags['a'], bags['b']], out, backends=['null'], params=[], max_frames=8)
    assert first.status == 'complete'
    assert reads == []  # the cells' figures came back with them: nothing read after a cell
    rows = list(csv.DictReader((out / 'sweep.csv').open(encoding='utf-8')))
    assert [r['cell'] for r in rows] == [c.cell for c in first.sweep.cells]

    second = _sweep([bags['a'], bags['b']], out, backends=['null', 'hsv'], max_frames=8)
    assert second.status == 'complete'
    assert second.sweep.counts.resumed == 2
    # each kept cell's run.json once (is it complete, with this key?); figures from sweep.json
    assert sorted(r.split('/')[-2] for r in reads) == sorted(c.cell for c in first.sweep.cells)
    assert [c.metrics for c in second.sweep.cells if c.resumed] == [
        c.metrics for c in first.sweep.cells
    ]


def test_sweep_csv_grows_by_one_appended_row_per_finished_cell(tmp_path: Path) -> None:
    from replaybench.app.sweep.record import CSV_COLUMNS, CsvLog, csv_row
    from replaybench.results.sweepfile import SweepCell

    path = tmp_path / 'sweep.csv'
    log = CsvLog(path, [])
    sizes = [path.stat().st_size]
    inode = path.stat().st_ino
    for n in range(3):
        log.append(csv_row(SweepCell(index=n, cell=f'c{n}', key='k', status='failed')))
        sizes.append(path.stat().st_size)
    assert path.stat().st_ino == inode  # appended, not rewritten
    assert len({b - a for a, b in itertools.pairwise(sizes)}) == 1
    rows = list(csv.DictReader(path.open(encoding='utf-8')))
    assert [r['cell'] for r in rows] == ['c0', 'c1', 'c2']
    assert list(rows[0]) == list(CSV_COLUMNS)


def _coco(bag: Path, path: Path) -> str:
    """A COCO file boxing the middle of each frame of ``bag``'s image topic, ids from 1."""
    from replaybench.decode import decode_image
    from replaybench.sources import open_source

    images, annotations = [], []
    with open_source(bag) as source:
        (topic,) = [t.name for t in source.topics() if 'Image' in t.msgtype]
        for raw in source.messages(topics=[topic]):
            image = decode_image(raw)
            images.append({'id': raw.seq + 1, 'file_name': f'{raw.seq}.png'})
            box = [image.width / 4, image.height / 4, image.width / 2, image.height / 2]
            annotations.append({'image_id': raw.seq + 1, 'category_id': 1, 'bbox': box})
    cats = [{'id': 1, 'name': 'thing'}]
    doc = {'images': images, 'annotations': annotations, 'categories': cats}
    path.write_text(json.dumps(doc), encoding='utf-8')
    return topic


def test_the_run_options_the_sweep_lacked_reach_each_cell(
    bags: dict[str, Path], tmp_path: Path
) -> None:
    gt = tmp_path / 'gt.json'
    topic = _coco(bags['a'], gt)
    result = _sweep(
        [bags['a']],
        tmp_path / 'sw',
        backends=['hsv'],
        detections_format='rosbag2',
        hash_inputs=False,
        ground_truth_file=gt,
        ground_truth_match='seq',
        ground_truth_image_topic=topic,
        ground_truth_seq_offset=1,
        device=0,
    )
    assert result.status == 'complete', result.record['cells']
    (cell,) = result.record['cells']
    folder = tmp_path / 'sw' / cell['run_dir']
    assert (folder / 'metadata.yaml').is_file()  # --format rosbag2
    run = json.loads((folder / 'run.json').read_text(encoding='utf-8'))
    settings = run['settings']
    assert settings['ground_truth_file'] == str(gt.resolve())
    assert settings['ground_truth_match'] == 'seq'
    assert run['inputs'][0]['sha256'] is None  # --no-hash
    assert result.record['inputs'][0]['sha256'] is None
    assert result.record['settings']['hash_inputs'] is False
    assert result.record['settings']['detections_format'] == 'rosbag2'
    assert result.record['settings']['ground_truth_seq_offset'] == 1
    assert result.record['settings']['ground_truth_image_topic'] == topic
    assert run['summary'][0]['accuracy'] is not None  # scored against the file
    assert cell['metrics']['map50'] is not None


def test_a_cell_of_a_segmentation_or_tag_backend_carries_its_accuracy(tmp_path: Path) -> None:
    """sweep.csv's miou / tag_recall / tag_rot_err_deg: the cell's mean over its topics, from
    the run's own summary rows; empty for a detector."""
    import dataclasses

    import replaybench as rb
    from replaybench.app.sweep.record import CSV_COLUMNS, cell_metrics
    from replaybench.fixtures.writer import write_mcap

    bag = write_mcap(tmp_path / 'seg.mcap', 6, (160, 120), masks=True)
    run = rb.run(bag, backends=['hsv-seg', 'hsv'], warmup=0)
    seg, det = run.summary_rows  # in the order of the backends
    assert seg.miou is not None
    assert det.miou is None
    for row in (seg, det):
        records = [r for r in run.frame_records or () if r.backend == row.backend]
        metrics = cell_metrics(dataclasses.replace(run, summary_rows=(row,)), records, '0' * 16)
        assert metrics.miou == row.miou
        assert metrics.tag_recall is None
        assert metrics.tag_rot_err_deg is None
    assert {'miou', 'tag_recall', 'tag_rot_err_deg'} <= set(CSV_COLUMNS)
