"""Outputs of the engine on the bundled fixtures, kept and compared across code changes.

``python -m benchmarks.outputs_identity make DIR`` runs a set of cases (several fixtures,
backends, rates and output options, through the command line and through ``rb.run`` in
memory and into a folder) into ``DIR``; ``python -m benchmarks.outputs_identity check REF NEW``
compares two such folders: detections.mcap and the sample pictures byte for byte, frames.csv,
summary.csv and run.json cell by cell, timing values aside (a timing value is compared only
for being present or empty). Exit status 0 when every case is identical, 1 otherwise, with
one line per difference.

Columns and keys added since a reference was made (``ADDED``: the tag columns of frames.csv and
summary.csv and run.json's ``tag_accuracy``) are expected in the new outputs: where the
reference lacks one, the new value must be empty (no case runs a tag backend) and is then left
out of the comparison; a filled one is a difference.
"""

from __future__ import annotations

import csv
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

#: columns and keys a newer engine adds, empty in these cases (no tag backend runs): frames.csv's
#: tag columns, summary.csv's (and run.json's summary rows') and run.json's ``tag_accuracy``
ADDED: tuple[str, ...] = (
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
    'tag_accuracy',
)

#: JSON keys and CSV columns holding a time, a rate or a resource reading: compared only for
#: being present (a number) or empty (null)
_TIMING = re.compile(
    r'(_s|_ms|_fps|_ms_mean|_std|_min|_max|_p\d+|_peak|_ci_low|_ci_high|_mean|_mhz|_w)$'
    r'|^(started_at|finished_at|load_average|t_s|wall_s|record_s|cpu_percent|private_mb|'
    r'mapped_mb|rss_mb|samples|used|probe_frames|jitter_ms|throughput_fps)$'
)
#: subtrees compared by their keys only (what the machine did meanwhile: a resource figure is
#: null when the pass ended before the sampler's first timed sample)
_SHAPE_ONLY = {'resources', 'environment'}
#: keys whose value is a detection count or accuracy, never timing, though the pattern matches
_NOT_TIMING = {'detections_per_frame'}


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
    if key in {'path', 'executable'} and isinstance(value, str):
        return Path(value).name
    return value


def _shape(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _shape(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_shape(v) for v in value[:1]]
    return '<value>'  # what the machine measured meanwhile, present or not


def _diff(a: Any, b: Any, where: str, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        if list(a) != list(b):
            out.append(f'{where}: keys {list(a)} != {list(b)}')
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


def _drop_added(a: Any, b: Any, where: str, out: list[str]) -> Any:
    """``b`` without the ``ADDED`` keys ``a`` lacks (each must be empty in ``b``: a filled one
    is reported), at every depth; a CSV's header row loses those columns too."""
    if isinstance(a, dict) and isinstance(b, dict):
        kept = {}
        for k, v in b.items():
            if k in ADDED and k not in a:
                if v not in (None, ''):
                    out.append(f'{where}.{k}: {v!r}, expected empty (no tag backend ran)')
                continue
            kept[k] = _drop_added(a[k], v, f'{where}.{k}', out) if k in a else v
        if list(kept) == ['<header>'] and '<header>' in a:
            ref_columns = set(a['<header>'].split(','))
            kept['<header>'] = ','.join(
                c for c in kept['<header>'].split(',') if c in ref_columns or c not in ADDED
            )
        return kept
    if isinstance(a, list) and isinstance(b, list):
        pairs = enumerate(zip(a, b, strict=False))  # a length difference is _diff's to report
        rows = [_drop_added(x, y, f'{where}[{i}]', out) for i, (x, y) in pairs]
        return rows + b[len(rows) :]
    return b


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

    return [
        {
            k: ('<number>' if v is not None else None) if _timing(k) else v
            # a reference's rows end where its columns did (the ADDED ones come last)
            for k, v in zip(FRAMES_CSV_COLUMNS[: len(row)], row, strict=True)
        }
        for row in document.pop('frame_records')
    ]


def _compare_folder(ref: Path, new: Path, where: str, out: list[str]) -> None:
    names_ref = sorted(p.relative_to(ref).as_posix() for p in ref.rglob('*') if p.is_file())
    names_new = sorted(p.relative_to(new).as_posix() for p in new.rglob('*') if p.is_file())
    if names_ref != names_new:
        out.append(f'{where}: files {names_ref} != {names_new}')
    for name in names_ref:
        a, b = ref / name, new / name
        if not b.exists():
            continue
        if name.endswith(('.mcap', '.jpg', '.png', '.yaml')):
            if a.read_bytes() != b.read_bytes():
                out.append(f'{where}/{name}: bytes differ')
        elif name.endswith('.csv'):
            ca, cb = _csv(a), _csv(b)
            _diff(ca, _drop_added(ca, cb, f'{where}/{name}', out), f'{where}/{name}', out)
        elif Path(name).name == 'run.json':
            ma = _masked(json.loads(a.read_text(encoding='utf-8')))
            mb = _masked(json.loads(b.read_text(encoding='utf-8')))
            _diff(ma, _drop_added(ma, mb, f'{where}/{name}', out), f'{where}/{name}', out)
        elif name.endswith('.json'):  # an API result document
            da = json.loads(a.read_text(encoding='utf-8'))
            db = json.loads(b.read_text(encoding='utf-8'))
            fa, fb = _frames_records(da), _frames_records(db)
            here = f'{where}/{name}:frames'
            _diff(fa, _drop_added(fa, fb, here, out), here, out)
            ma, mb = _masked(da), _masked(db)
            _diff(ma, _drop_added(ma, mb, f'{where}/{name}', out), f'{where}/{name}', out)


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
