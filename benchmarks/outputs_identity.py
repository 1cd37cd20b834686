"""Outputs of the engine on the bundled fixtures, kept and compared across code changes.

``python -m benchmarks.outputs_identity make DIR`` runs a set of cases (several fixtures,
backends, rates and output options, through the command line and through ``rb.run`` in
memory and into a folder) into ``DIR``; ``python -m benchmarks.outputs_identity check REF NEW``
compares two such folders: outputs.mcap and the sample pictures byte for byte, frames.csv,
summary.csv and run.json cell by cell, timing values aside (a timing value is compared only
for being present or empty). Columns and keys that a newer engine adds (``ADDED_COLUMNS``,
``ADDED_KEYS``) may be missing from the reference: the new outputs must then hold them empty,
or at the value an older output stands for (``repeat`` 0: a single pass; none of the cases uses
what they report). run.json's ``settings`` without ``repeat`` reads as ``repeat`` 1. Exit
status 0 when every case is identical, 1 otherwise, with one line per difference.

A reference made before the run folder's MCAP was named outputs.mcap (run.json schema_version
1: ``detections.mcap``, ``outputs.detections_mcap``) is compared as its newer layout: its
detections.mcap against the new outputs.mcap byte for byte, its metadata.yaml (``--format
rosbag2``) with that file name changed, and its run.json's ``schema_version`` 1 and
``outputs.detections_mcap`` as 2 and ``outputs.outputs_mcap`` (``OLDER_LAYOUT``).

A reference made before the rig rows (``RIG_TOPIC``) is compared without the new outputs'
summary rows of topic ``rig`` and run.json's ``rig`` section, each such row checked to hold
its backend's camera rows' frames and drops summed.

A reference made before the recorded-latency columns (``RECORDED_ADDED``) is compared without
them: the new outputs may hold those columns beside the reference's (the ``recorded`` case
fills them), and every other cell must still match.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
BAGS = REPO / 'fixtures' / 'bags'

#: (name, arguments of ``replaybench run`` after the bags)
CLI_CASES: list[tuple[str, list[str]]] = [
    ('raw-hsv-null', ['rgb8_raw.mcap', '--backend', 'hsv', '--backend', 'null']),
    ('jpeg-onnx', ['jpeg.mcap', '--backend', 'onnx-cpu', '--backend', 'hsv', '--annotations']),
    (
        'two-inputs',
        ['rgb8_raw.mcap', 'rgb8.bag', '--backend', 'hsv', '--backend', 'null', '--no-report'],
    ),
    (
        'rosbag2-copy',
        ['bgr8_rosbag2', '--backend', 'hsv', '--format', 'rosbag2', '--copy-images', '--no-hash'],
    ),
    ('two-camera-recorded-rate', ['two_camera.mcap', '--backend', 'hsv', '--rate', 'recorded']),
    (
        'recorded-backend',
        [
            'rgb8_raw.mcap',
            '--backend',
            'recorded',
            '--backend',
            'hsv',
            '--recorded-topic',
            '/ground_truth/detections',
            '--warmup',
            '2',
            '--max-frames',
            '8',
        ],
    ),
    # the tag task: two detectors scored against the bag's tag truth, poses and the sizes the
    # bag records; a tag node's recorded outputs beside a replayed detector
    ('tags-two-detectors', ['../tags/tags.mcap', '--backend', 'aruco', '--backend', 'apriltag']),
    ('tags-recorded', ['../tags/live_tags.mcap', '--backend', 'recorded', '--backend', 'aruco']),
    # the segmentation task: recorded label masks beside both segmenters, mIoU and agreement
    (
        'masks-recorded',
        [
            'live_masks.mcap',
            '--backend',
            'recorded',
            '--backend',
            'hsv-seg',
            '--backend',
            'onnx-seg',
            '--recorded-topic',
            '/unet/raw_segmentation_mask',
        ],
    ),
]

#: ``rb.run`` cases: (name, positional bags, keyword options); each runs in memory and into a
#: folder, and both are kept.
API_CASES: list[tuple[str, list[str], dict[str, Any]]] = [
    ('api-hsv-null', ['rgb8_raw.mcap'], {'backends': ['hsv', 'null']}),
    ('api-two-camera', ['two_camera.mcap'], {'backends': ['hsv'], 'max_frames': 6}),
]

_API_SCRIPT = """
import json, sys
from pathlib import Path
import replaybench as rb
from replaybench.results.io import to_json
bags, options, out = json.loads(sys.argv[1]), json.loads(sys.argv[2]), Path(sys.argv[3])
memory = rb.run(bags, **options)
folder = rb.run(bags, out=out / 'folder', **options)
for name, result in (('memory', memory), ('folder-result', folder)):
    document = to_json(result)
    document['frame_records'] = [list(r) for r in result.frame_records]
    (out / f'{name}.json').write_text(json.dumps(document, indent=1), encoding='utf-8')
"""

#: JSON keys and CSV columns holding a time, a rate or a resource reading: compared only for
#: being present (a number) or empty (null)
_TIMING = re.compile(
    r'(_s|_ms|_fps|_ms_mean|_std|_min|_max|_p\d+|_peak|_ci_low|_ci_high|_mean|_mhz|_w)$'
    r'|^(started_at|finished_at|load_average|t_s|wall_s|record_s|cpu_percent|private_mb|'
    r'mapped_mb|rss_mb|samples|used|probe_frames|jitter_ms|throughput_fps)$'
)
#: subtrees compared by their keys only (what the machine did meanwhile: a resource figure is
#: null when the pass ended before the sampler's first timed sample)
#: (the worst camera by p99 is whichever camera's p99 was highest: a timing)
_SHAPE_ONLY = {'resources', 'environment', 'worst_p99'}
#: keys whose value is a detection count or accuracy, never timing, though the pattern matches
_NOT_TIMING = {'detections_per_frame'}


#: frames.csv and summary.csv columns added since a reference may have been made: the pass of
#: ``--repeat`` (0: the single pass), the segmentation scores and the tag columns (empty: no
#: segmentation or tag backend runs in these cases)
ADDED_COLUMNS: tuple[str, ...] = (
    'repeat',
    'miou',
    'pixel_accuracy',
    'tags',
    'tag_truth',
    'tag_matched',
    'tag_wrong_ids',
    'tag_phantoms',
    'tag_corner_rmse_px',
    'tag_trans_err_m',
    'tag_rot_err_deg',
    'tag_recall',
    'tag_trans_err_pct',
    # frames.csv's pipeline that served the frame: 0 where one instance serves every topic
    'pipeline',
    # a task's frame values without fields of their own: None for the built-in tasks
    'task_values',
)
#: what an added column holds in outputs that stand for an older one's absence
_OLDER_VALUES: dict[str, tuple[Any, ...]] = {'repeat': (0, '0'), 'pipeline': (0, '0')}
#: run.json / result keys added likewise (null or empty in these cases)
ADDED_KEYS: tuple[str, ...] = (
    *ADDED_COLUMNS,
    'segmentation',
    'segmentation_agreement',
    'tag_accuracy',
    # settings.pipelines: null for --pipelines shared, which every case runs
    'pipelines',
)


def _empty(value: Any, key: str = '') -> bool:
    return value is None or value in ('', [], {}) or value in _OLDER_VALUES.get(key, ())


#: columns added to frames.csv, summary.csv and run.json's summary rows since outputs were
#: first kept (recorded outputs' latency, replaybench.results.recorded_latency), and the
#: ``recorded`` backend's ``recorded_latency`` line in its run.json info: left out of the new
#: side where the reference has none of them
RECORDED_ADDED: frozenset[str] = frozenset(
    {
        'recorded_latency',
        'output_log_time_ns',
        'capture_to_output_ms',
        'pipeline_ms',
        'recorded_outputs',
        'recorded_outputs_dropped',
        'recorded_output_hz',
        *(
            f'{figure}_{stat}'
            for figure in ('capture_to_output_ms', 'pipeline_ms')
            for stat in (
                'mean',
                'p50',
                'p50_ci_low',
                'p50_ci_high',
                'p99',
                'p99_ci_low',
                'p99_ci_high',
                'max',
            )
        ),
        'recorded_latency_note',
    }
)


#: warnings that report a measured time (the latency's spread, its drift, a hash overlapping
#: the passes): left out of the comparison
_TIMED_WARNINGS = re.compile(
    r'^(unstable latency|latency drift)|computed during the first|^95 % interval of the ratio'
)


def _warnings(items: list[str]) -> list[str]:
    return [w for w in items if not _TIMED_WARNINGS.search(w)]


def _timing(key: str) -> bool:
    return key not in _NOT_TIMING and _TIMING.search(key) is not None


def _env() -> dict[str, str]:
    return {**os.environ, 'PYTHONPATH': str(REPO)}


def make(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    exe = [sys.executable, '-m', 'replaybench']
    for name, args in CLI_CASES:
        bags = [str(BAGS / a) if (BAGS / a).exists() else a for a in args]
        proc = subprocess.run(
            [*exe, 'run', *bags, '--out', str(out / name), '--force'],
            cwd=REPO,
            env=_env(),
            capture_output=True,
            text=True,
            check=False,
        )
        if proc.returncode != 0:
            sys.exit(f'{name}: exit {proc.returncode}: {proc.stderr.strip()}')
        print(f'{name}: written')
    for name, bags, options in API_CASES:
        where = out / name
        where.mkdir(parents=True, exist_ok=True)
        proc = subprocess.run(
            [
                sys.executable,
                '-c',
                _API_SCRIPT,
                json.dumps([str(BAGS / b) for b in bags]),
                json.dumps(options),
                str(where),
            ],
            cwd=REPO,
            env=_env(),
            capture_output=True,
            text=True,
            check=False,
        )
        if proc.returncode != 0:
            sys.exit(f'{name}: exit {proc.returncode}: {proc.stderr.strip()[-2000:]}')
        print(f'{name}: written')


def _masked(value: Any, key: str = '') -> Any:
    if key in _SHAPE_ONLY and isinstance(value, dict):
        return _shape(value)
    if isinstance(value, dict):
        return {k: _masked(v, k) for k, v in value.items()}
    if key == 'warnings' and isinstance(value, list):
        return _warnings(value)
    if key == 'command' and isinstance(value, list):
        return [Path(v).name if '/' in v else v for v in value]
    if isinstance(value, list):
        return [_masked(v, key) for v in value]
    if _timing(key) and not isinstance(value, str | bool):
        return None if value is None else '<number>'
    if key in {'started_at', 'finished_at'}:
        return '<time>'
    if key in {'path', 'executable', 'model'} and isinstance(value, str):
        return Path(value).name
    return value


def _shape(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _shape(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_shape(v) for v in value[:1]]
    return '<value>'  # what the machine measured meanwhile, present or not


def _without_added(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """``b`` without the ``RECORDED_ADDED`` columns that ``a`` (the reference) lacks; a CSV
    header (``<header>``) likewise."""
    if '<header>' in a and '<header>' in b:
        ref = set(a['<header>'].split(','))
        names = [n for n in b['<header>'].split(',') if n in ref or n not in RECORDED_ADDED]
        return {**b, '<header>': ','.join(names)}
    return {k: v for k, v in b.items() if k in a or k not in RECORDED_ADDED}


def _diff(a: Any, b: Any, where: str, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        b = _without_added(a, b)
        # an added key missing from the reference: allowed when empty in the new outputs
        keys_b = [k for k in b if k in a or k not in ADDED_KEYS or not _empty(b[k], k)]
        if list(a) != keys_b:
            out.append(f'{where}: keys {list(a)} != {keys_b}')
        for k in a:
            if k in b:
                _diff(a[k], b[k], f'{where}.{k}', out)
        return
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f'{where}: {len(a)} items != {len(b)}')
        for i, (x, y) in enumerate(zip(a, b, strict=False)):
            _diff(x, y, f'{where}[{i}]', out)
        return
    if a != b or type(a) is not type(b):
        out.append(f'{where}: {a!r} != {b!r}')


#: a run.json setting added since, and the value an older run.json stands for
_ADDED_SETTING = ('repeat', 1)
#: run.json schema_version 1 -> 2: (the MCAP's older file name, its newer one, the older and
#: newer key of ``outputs`` naming it)
OLDER_LAYOUT = ('detections.mcap', 'outputs.mcap', 'detections_mcap', 'outputs_mcap')


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(encoding='utf-8', newline='') as file:
        rows = list(csv.reader(file))
    header, body = rows[0], rows[1:]
    return [
        {
            k: ('<number>' if v else '')
            if _timing(k)
            else '; '.join(_warnings(v.split('; ')))
            if k == 'warnings'
            else v
            for k, v in zip(header, row, strict=True)
        }
        for row in body
    ] + [{'<header>': ','.join(header)}]


def _frames_records(document: dict[str, Any]) -> list[Any]:
    from replaybench.results.records import FRAMES_CSV_COLUMNS

    # a record's task values (FrameRecord.task_values, after the columns) are a mapping of the
    # frame values of a task without fields, None for the built-in tasks: compared as a column
    rows = document.pop('frame_records')
    with_tasks = (*FRAMES_CSV_COLUMNS, 'task_values')
    before = tuple(
        c for c in FRAMES_CSV_COLUMNS if c not in ADDED_COLUMNS and c not in RECORDED_ADDED
    )
    # a record of this engine, of one before the pipeline column, or of one before the added
    # columns, told apart by its length
    layouts = {
        len(columns): columns
        for columns in (before, FRAMES_CSV_COLUMNS[:-1], FRAMES_CSV_COLUMNS, with_tasks)
    }
    return [
        {
            k: ('<number>' if v is not None else None) if _timing(k) else v
            for k, v in zip(layouts.get(len(row), FRAMES_CSV_COLUMNS), row, strict=True)
        }
        for row in rows
    ]


def _with_added_setting(document: dict[str, Any]) -> dict[str, Any]:
    """A run.json (or API document) written before ``settings.repeat``, as a single pass."""
    settings = document.get('settings')
    name, value = _ADDED_SETTING
    if isinstance(settings, dict) and name not in settings:
        document['settings'] = {**settings, name: value}
    return document


def _as_newer(document: dict[str, Any]) -> dict[str, Any]:
    """A run.json (or API document) of schema_version 1 in the layout of 2 (``OLDER_LAYOUT``):
    the key naming the MCAP renamed in its place, and its value the newer file name."""
    if document.get('schema_version') != 1:
        return document
    old_file, new_file, old_key, new_key = OLDER_LAYOUT
    outputs = document.get('outputs')
    if isinstance(outputs, dict) and old_key in outputs:
        document['outputs'] = {
            (new_key if k == old_key else k): (new_file if v == old_file else v)
            for k, v in outputs.items()
        }
    return {**document, 'schema_version': 2}


def _older(folder: Path) -> bool:
    """Whether ``folder`` is a run folder of run.json schema_version 1 (detections.mcap)."""
    old_file, new_file = OLDER_LAYOUT[:2]
    return (folder / old_file).is_file() and not (folder / new_file).is_file()


def _ref_bytes(path: Path) -> bytes:
    """A reference file's bytes; an older run folder's metadata.yaml naming the newer MCAP."""
    data = path.read_bytes()
    if path.name == 'metadata.yaml' and _older(path.parent):
        old_file, new_file = OLDER_LAYOUT[:2]
        data = data.replace(old_file.encode(), new_file.encode())
    return data


def _ref_name(ref: Path, path: Path) -> str:
    """A reference file's name relative to ``ref``; an older run folder's MCAP by its newer name."""
    old_file, new_file = OLDER_LAYOUT[:2]
    if path.name == old_file and _older(path.parent):
        path = path.with_name(new_file)
    return path.relative_to(ref).as_posix()


def _shifted(record: Any, delta: int, after: int) -> Any:
    """A summary record of a reference's MCAP with the file offsets past ``after`` moved by
    ``delta`` (what a shorter or longer rosbag2 metadata record at ``after`` moves them by); the
    footer's CRC of the summary left out (it covers those offsets)."""
    from mcap.records import AttachmentIndex, ChunkIndex, Footer, MetadataIndex, SummaryOffset

    if isinstance(record, ChunkIndex):
        offsets = {k: v + delta for k, v in record.message_index_offsets.items()}
        return dataclasses.replace(
            record,
            chunk_start_offset=record.chunk_start_offset + delta,
            message_index_offsets=offsets,
        )
    if isinstance(record, MetadataIndex) and record.offset == after:
        return dataclasses.replace(record, length=record.length + delta)
    if isinstance(record, MetadataIndex | AttachmentIndex) and record.offset > after:
        return dataclasses.replace(record, offset=record.offset + delta)
    if isinstance(record, SummaryOffset):
        return dataclasses.replace(record, group_start=record.group_start + delta)
    if isinstance(record, Footer):
        return dataclasses.replace(
            record,
            summary_start=record.summary_start + delta,
            summary_offset_start=record.summary_offset_start + delta,
            summary_crc=0,
        )
    return record


def _same_mcap_renamed(ref: bytes, new: bytes) -> bool:
    """Whether ``new`` is the MCAP ``ref`` (an older run folder's detections.mcap) written as
    outputs.mcap: the file name in its rosbag2 metadata record (which names the bag's file, as
    ``ros2 bag record`` writes it) is the one difference. The header and the whole data section
    after that record (chunks, message indexes) are compared byte for byte, the record by
    content with the name changed, the summary record by record, its offsets moved by the
    difference in length."""
    import io

    from mcap.records import DataEnd, Footer, Metadata, MetadataIndex
    from mcap.stream_reader import StreamReader

    def records(data: bytes) -> list[Any]:
        return list(StreamReader(io.BytesIO(data), skip_magic=False).records)

    old_file, new_file = OLDER_LAYOUT[:2]
    rec_a, rec_b = records(ref), records(new)
    index = [
        next(r for r in recs if isinstance(r, MetadataIndex) and r.name == 'rosbag2')
        for recs in (rec_a, rec_b)
    ]
    meta = [
        next(r for r in recs if isinstance(r, Metadata) and r.name == 'rosbag2')
        for recs in (rec_a, rec_b)
    ]
    start_a, start_b = (
        next(r for r in recs if isinstance(r, Footer)).summary_start for recs in (rec_a, rec_b)
    )
    delta = start_b - start_a
    end_a, end_b = index[0].offset + index[0].length, index[1].offset + index[1].length
    renamed = {k: v.replace(old_file, new_file) for k, v in meta[0].metadata.items()}
    summary_a = rec_a[next(i for i, r in enumerate(rec_a) if isinstance(r, DataEnd)) :]
    summary_b = rec_b[next(i for i, r in enumerate(rec_b) if isinstance(r, DataEnd)) :]
    return (
        index[0].offset == index[1].offset
        and end_b - end_a == delta
        and ref[: index[0].offset] == new[: index[1].offset]
        and ref[end_a:start_a] == new[end_b:start_b]
        and renamed == meta[1].metadata
        and [_shifted(r, delta, index[0].offset) for r in summary_a]
        == [_shifted(r, 0, index[1].offset) for r in summary_b]
        and ref[-8:] == new[-8:]
    )


#: a newer engine's rig rows: where a reference holds none, the new outputs' summary rows of
#: topic ``rig`` (summary.csv, run.json's ``summary``) and run.json's ``rig`` section are left
#: out of the comparison, nothing else; each such row must still hold its backend's camera
#: rows' frames and drops summed (the two-camera cases gain one per backend)
RIG_TOPIC = 'rig'


def _without_rig_rows(
    rows_a: list[dict[str, Any]], rows_b: list[dict[str, Any]], where: str, out: list[str]
) -> list[dict[str, Any]]:
    """``rows_b`` without its rig rows where ``rows_a`` (the reference's) has none, each
    checked against the sums of its backend's other rows."""
    if any(r.get('topic') == RIG_TOPIC for r in rows_a):
        return rows_b
    kept = [r for r in rows_b if r.get('topic') != RIG_TOPIC]
    for row in rows_b:
        if row.get('topic') != RIG_TOPIC:
            continue
        cameras = [r for r in kept if r.get('backend') == row['backend']]
        for key in ('frames', 'dropped'):
            total = sum(int(r[key]) for r in cameras)
            if int(row[key]) != total or len(cameras) < 2:
                out.append(
                    f'{where}: rig row of {row["backend"]}: {key} {row[key]} is not the sum '
                    f'{total} of {len(cameras)} camera rows'
                )
    return kept


def _without_rig(a: dict[str, Any], b: dict[str, Any], where: str, out: list[str]) -> None:
    """A run.json (or API document) ``b`` without the rig rows and the ``rig`` section that
    the reference ``a`` lacks (``RIG_TOPIC``), in place."""
    if 'rig' in a or not isinstance(b.get('summary'), list):
        return
    b['summary'] = _without_rig_rows(a.get('summary') or [], b['summary'], where, out)
    b.pop('rig', None)


def _compare_folder(ref: Path, new: Path, where: str, out: list[str]) -> None:
    files_ref = {_ref_name(ref, p): p for p in ref.rglob('*') if p.is_file()}
    names_ref = sorted(files_ref)
    names_new = sorted(p.relative_to(new).as_posix() for p in new.rglob('*') if p.is_file())
    if names_ref != names_new:
        out.append(f'{where}: files {names_ref} != {names_new}')
    for name in names_ref:
        a, b = files_ref[name], new / name
        if not b.exists():
            continue
        if a.name == OLDER_LAYOUT[0] and b.name == OLDER_LAYOUT[1]:
            if not _same_mcap_renamed(a.read_bytes(), b.read_bytes()):
                out.append(f'{where}/{name}: not the reference {a.name} renamed')
        elif name.endswith(('.mcap', '.jpg', '.png', '.yaml')):
            if _ref_bytes(a) != b.read_bytes():
                out.append(f'{where}/{name}: bytes differ')
        elif name.endswith('.csv'):
            rows_a, rows_b = _csv(a), _csv(b)
            header_a = rows_a[-1]['<header>'].split(',')
            header_b = rows_b[-1]['<header>'].split(',')
            rows_b[-1]['<header>'] = ','.join(
                c for c in header_b if c in header_a or c not in ADDED_COLUMNS
            )
            if Path(name).name == 'summary.csv':
                rows_b = _without_rig_rows(rows_a, rows_b, f'{where}/{name}', out)
            _diff(rows_a, rows_b, f'{where}/{name}', out)
        elif Path(name).name == 'run.json':
            ra = _as_newer(json.loads(a.read_text(encoding='utf-8')))
            rb = json.loads(b.read_text(encoding='utf-8'))
            _without_rig(ra, rb, f'{where}/{name}', out)
            _diff(
                _masked(_with_added_setting(ra)),
                _masked(_with_added_setting(rb)),
                f'{where}/{name}',
                out,
            )
        elif name.endswith('.json'):  # an API result document
            da = _as_newer(json.loads(a.read_text(encoding='utf-8')))
            db = json.loads(b.read_text(encoding='utf-8'))
            _without_rig(da, db, f'{where}/{name}', out)
            _diff(_frames_records(da), _frames_records(db), f'{where}/{name}:frames', out)
            da, db = _with_added_setting(da), _with_added_setting(db)
            _diff(_masked(da), _masked(db), f'{where}/{name}', out)


def check(ref: Path, new: Path) -> int:
    problems: list[str] = []
    cases = [name for name, _ in CLI_CASES] + [name for name, _, _ in API_CASES]
    for name in cases:
        if not (new / name).is_dir():
            problems.append(f'{name}: missing in {new}')
            continue
        _compare_folder(ref / name, new / name, name, problems)
    for line in problems:
        print(line)
    print(f'{len(cases)} cases, {len(problems)} difference(s)')
    return 1 if problems else 0


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == 'make':
        make(Path(argv[1]))
        return 0
    if len(argv) == 3 and argv[0] == 'check':
        return check(Path(argv[1]), Path(argv[2]))
    print(__doc__)
    return 2


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
