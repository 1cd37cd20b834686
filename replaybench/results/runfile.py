"""The run folder's files: run.json, summary.csv, and the machine description stored in run.json."""

from __future__ import annotations

import io
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from importlib import metadata
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench._version import __version__
from replaybench.errors import SourceError
from replaybench.results.model import RUN_SCHEMA_VERSION
from replaybench.results.records import FrameRecord, csv_writer, read_frames_csv
from replaybench.results.runfolder import with_filename
from replaybench.results.stats import SUMMARY_CSV_COLUMNS, summary_row
from replaybench.textsafe import csv_text

if TYPE_CHECKING:
    from collections.abc import Iterable

    from replaybench.results.model import RunResult
    from replaybench.results.stats import Summary

__all__ = [
    'SCHEMA_VERSION',
    'RunData',
    'environment',
    'json_text',
    'load_run',
    'write_json_atomic',
    'write_run_json',
    'write_summary_csv',
    'write_text_atomic',
]

#: Version of the run.json layout (``RUN_SCHEMA_VERSION``); readers refuse files with a newer one.
SCHEMA_VERSION = RUN_SCHEMA_VERSION

_DISTRIBUTIONS: dict[str, tuple[str, ...]] = {
    'numpy': ('numpy',),
    'onnxruntime': (
        'onnxruntime',
        'onnxruntime-gpu',
        'onnxruntime-openvino',
        'onnxruntime-directml',
    ),
    'mcap': ('mcap',),
    'rosbags': ('rosbags',),
}


class RunData(NamedTuple):
    """A run folder as read back: run.json (typed), frames.csv rows and the folder."""

    run: RunResult
    frames: list[FrameRecord]
    dir: Path


def _version(names: Iterable[str]) -> str | None:
    for name in names:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return None


def _read_text(path: str) -> str | None:
    try:
        return Path(path).read_text(encoding='utf-8', errors='replace')
    except OSError:
        return None


def _cpu_model() -> str:
    text = _read_text('/proc/cpuinfo')
    if text:
        for key in ('model name', 'Model', 'Hardware', 'cpu model'):
            for line in text.splitlines():
                name, sep, value = line.partition(':')
                if sep and name.strip() == key and value.strip():
                    return value.strip()
    return platform.processor() or platform.machine()


def _memory_total_bytes() -> int | None:
    text = _read_text('/proc/meminfo')
    if text:
        for line in text.splitlines():
            if line.startswith('MemTotal:'):
                parts = line.split()
                if len(parts) >= 2 and parts[1].isdigit():
                    return int(parts[1]) * 1024
    return None


def _usable_cores() -> int | None:
    if hasattr(os, 'sched_getaffinity'):
        return len(os.sched_getaffinity(0))
    return os.cpu_count()


def _opencv() -> dict[str, Any]:
    try:
        import cv2
    except ImportError:
        return {'version': None, 'threads': None}
    return {'version': str(cv2.__version__), 'threads': int(cv2.getNumThreads())}


def _gpus() -> list[dict[str, str]]:
    exe = shutil.which('nvidia-smi')
    if exe is None:
        return []
    try:
        proc = subprocess.run(
            [exe, '--query-gpu=name,driver_version,memory.total', '--format=csv,noheader'],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return []
    if proc.returncode != 0:
        return []
    gpus = []
    for line in proc.stdout.splitlines():
        parts = [part.strip() for part in line.split(',')]
        if len(parts) == 3 and parts[0]:
            gpus.append({'name': parts[0], 'driver_version': parts[1], 'memory_total': parts[2]})
    return gpus


def environment() -> dict[str, Any]:
    """Describe this machine and the library versions that shape the measurements."""
    governor = _read_text('/sys/devices/system/cpu/cpu0/cpufreq/scaling_governor')
    try:
        load: list[float] | None = [round(v, 2) for v in os.getloadavg()]
    except OSError:
        load = None
    return {
        'hostname': platform.node() or None,
        'cpu': {
            'model': _cpu_model(),
            'logical_cores': os.cpu_count(),
            'usable_cores': _usable_cores(),
            'machine': platform.machine(),
            'governor': governor.strip() if governor else None,
        },
        'memory_total_bytes': _memory_total_bytes(),
        'os': {
            'system': platform.system(),
            'release': platform.release(),
            'version': platform.version(),
            'platform': platform.platform(),
        },
        'python': {
            'version': platform.python_version(),
            'implementation': platform.python_implementation(),
            'executable': sys.executable,
        },
        'packages': {
            'replaybench': __version__,
            **{key: _version(names) for key, names in _DISTRIBUTIONS.items()},
            'opencv': _opencv(),
        },
        'load_average': load,
        'gpus': _gpus(),
    }


def _jsonable(obj: Any) -> Any:
    """Plain JSON types; NaN and infinities become None."""
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(key): _jsonable(value) for key, value in obj.items()}
    if isinstance(obj, list | tuple | set | frozenset):
        items = sorted(obj, key=repr) if isinstance(obj, set | frozenset) else obj
        return [_jsonable(value) for value in items]
    if isinstance(obj, PurePath):
        return str(obj)
    item = getattr(obj, 'item', None)
    if callable(item) and type(obj).__module__ == 'numpy':
        return _jsonable(item())
    msg = f'cannot store {type(obj).__name__} in JSON'
    raise TypeError(msg)


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write UTF-8 text via a temporary file in the same folder and ``os.replace``.

    A failed write leaves nothing behind and raises ``OSError`` naming ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(fd, 'w', encoding='utf-8', newline='') as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        Path(tmp).chmod(0o644)
        Path(tmp).replace(path)
    except OSError as err:
        Path(tmp).unlink(missing_ok=True)
        raise with_filename(err, path) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def json_text(obj: Any) -> str:
    """``obj`` as the indented JSON text ``write_json_atomic`` writes (NaN and infinities
    as null, key order kept)."""
    return json.dumps(_jsonable(obj), indent=2, sort_keys=False, allow_nan=False) + '\n'


def write_json_atomic(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON via a temporary file and ``os.replace``.

    NaN and infinite floats are written as null; key order is kept.
    """
    write_text_atomic(path, json_text(obj))


def write_run_json(path: str | Path, run: dict[str, Any]) -> None:
    """Write run.json atomically, adding ``schema_version`` first when it is missing."""
    if 'schema_version' not in run:
        run = {'schema_version': SCHEMA_VERSION, **run}
    write_json_atomic(path, run)


def summary_cell(value: Any) -> str:
    """One summary.csv cell: floats to 4 decimals, non-finite and None empty, text escaped."""
    if value is None:
        return ''
    if isinstance(value, bool):
        return '1' if value else '0'
    if isinstance(value, float):
        return format(value, '.4f') if math.isfinite(value) else ''
    return csv_text(value) if isinstance(value, str) else str(value)


def write_summary_csv(path: str | Path, summaries: Iterable[Summary]) -> None:
    """Write summary.csv (columns ``SUMMARY_CSV_COLUMNS``) atomically."""
    buffer = io.StringIO()
    writer = csv_writer(buffer)
    writer.writerow(SUMMARY_CSV_COLUMNS)
    for summary in summaries:
        row = summary_row(summary)
        writer.writerow([summary_cell(row[name]) for name in SUMMARY_CSV_COLUMNS])
    write_text_atomic(path, buffer.getvalue())


def load_run(run_dir: str | Path) -> RunData:
    """Read a run folder; SourceError with the reason when it is not a readable run."""
    from replaybench.results.io import read_run_result

    run_dir = Path(run_dir)
    run_json = run_dir / 'run.json'
    if not run_dir.is_dir():
        msg = f'{run_dir}: not a directory (expected a replaybench run folder)'
        raise SourceError(msg) from None
    if not run_json.exists():
        msg = f'{run_dir}: no run.json (not a replaybench run folder, or the run did not finish)'
        raise SourceError(msg) from None
    run = read_run_result(run_json)
    name = run.outputs.frames_csv if run.outputs is not None else 'frames.csv'
    frames_csv = run_dir / (name or 'frames.csv')
    if not frames_csv.resolve().is_relative_to(run_dir.resolve()):
        msg = f'{run_json}: outputs.frames_csv {name!r} points outside the run folder'
        raise SourceError(msg) from None
    if not frames_csv.is_file():
        msg = f'{run_dir}: {frames_csv.name} is missing'
        raise SourceError(msg) from None
    return RunData(run=run, frames=read_frames_csv(frames_csv), dir=run_dir)
