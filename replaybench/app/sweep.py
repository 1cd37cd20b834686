"""``replaybench sweep``: one ordinary run per (input, backend, parameter combination), on Ray.

Each cell is exactly a ``replaybench run`` of one input through one backend (the same
``RunConfig`` the ``run`` command builds, through ``run_benchmark``), executed as a Ray task in
a fresh worker process on some node of a Ray cluster: a local one started for the sweep, or an
existing one joined with ``address``. The task returns the run folder's files to the driver,
which writes them under ``OUT/cells/<name>/`` (the nodes need no shared output folder, only
the inputs at the same path: each cell checks the input's size and hash first).

Placement (measurement validity first):

* a CPU cell holds one unit of the custom resource ``replaybench_timed_slot``, of which each
  node offers one: at most one timed CPU cell runs on a node at a time;
* a GPU cell (its backend declares ``device = 'cuda'``) holds one GPU (``num_gpus=1``): a node runs
  as many GPU cells as it has GPUs, one per GPU, and the cell records which one;
* ``pack=True`` drops the node slot: CPU cells fill every core (for accuracy-only sweeps).

Resume: a cell is identified by its key, the hash of the input's size and sha256, the backend,
its parameters, every run option and the replaybench version. A cell folder whose run.json is
complete and carries the same key is kept untouched; only missing, failed or interrupted cells
run again. Outputs: ``sweep.json`` (schema ``replaybench/schemas/sweep.schema.json``),
``sweep.csv`` (one row per cell) and ``sweep.html`` (inputs x backends). See docs/sweep.md.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import hashlib
import itertools
import json
import logging
import math
import os
import re
import secrets
import shutil
import signal
import socket
import stat
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench._version import __version__
from replaybench.backends.base import BackendOptions
from replaybench.errors import EngineError, ReplaybenchError, SourceError, UsageError

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping, Sequence

    import pandas as pd

    from replaybench.replay.runner import RunConfig
    from replaybench.results.model import RunResult

__all__ = [
    'CSV_COLUMNS',
    'DEFAULT_MAX_RETRIES',
    'LOCAL_NODE_IP',
    'NODE_SLOT',
    'SWEEP_SCHEMA_VERSION',
    'Cell',
    'InputId',
    'ParamAxis',
    'ProgressBar',
    'SweepConfig',
    'SweepProgress',
    'SweepResult',
    'SweepSettings',
    'cell_metrics',
    'cell_options',
    'csv_rows',
    'execute_cell',
    'input_identity',
    'join_auth_env',
    'local_ray',
    'parse_params',
    'plan_cells',
    'progress_bar',
    'result_lines',
    'run_sweep',
    'sweep',
    'sweep_config',
]

#: Version of the sweep.json layout.
SWEEP_SCHEMA_VERSION = 1
#: The custom Ray resource a timed CPU cell holds: each node offers one unit.
NODE_SLOT = 'replaybench_timed_slot'
#: Address the local Ray instance listens on: loopback only (Ray maps 127.0.0.1 itself to the
#: machine's network address, so another loopback address is used on Linux).
LOCAL_NODE_IP = '127.0.0.2' if sys.platform.startswith('linux') else None
#: Ray re-runs a cell this many times when its worker or node is lost (not on errors).
DEFAULT_MAX_RETRIES = 3
CELLS_DIR = 'cells'
#: sweep.csv columns, in order; ``SweepResult.cells`` has the same columns.
CSV_COLUMNS: tuple[str, ...] = (
    'cell',
    'input',
    'backend',
    'params',
    'status',
    'frames',
    'fps',
    'fps_low',
    'fps_high',
    'p50_ms',
    'p50_low',
    'p50_high',
    'p99_ms',
    'p99_low',
    'p99_high',
    'map50',
    'node',
    'gpu',
    'concurrency',
    'flags',
    'error',
    'run_dir',
    'key',
)

_AUTH_MODE = 'RAY_AUTH_MODE'
_AUTH_TOKEN = 'RAY_AUTH_TOKEN'
_AUTH_TOKEN_PATH = 'RAY_AUTH_TOKEN_PATH'
_PROCESS_TOKEN: list[str] = []
_FLOAT_KEYS = ('conf', 'iou')
_PATH_KEYS = ('config', 'model')
_STR_KEYS = ('model_family', 'labels', 'engine', 'precision')
_UNSAFE = re.compile(r'[^A-Za-z0-9._=+-]+')


# --------------------------------------------------------------------------- planning


class ParamAxis(NamedTuple):
    """One ``--param BACKEND.KEY=V1,V2,...``: the values one option of one backend takes."""

    backend: str
    key: str
    values: tuple[str, ...]


def parse_params(texts: Sequence[str], backends: Sequence[str]) -> tuple[ParamAxis, ...]:
    """The ``--param`` options as axes; UsageError for a malformed one or an unswept backend."""
    axes: list[ParamAxis] = []
    seen: set[tuple[str, str]] = set()
    for text in texts:
        spec, eq, values = text.partition('=')
        backend, dot, key = spec.strip().partition('.')
        backend, key = backend.strip(), key.strip()
        if not (eq and dot and backend and key):
            msg = f'invalid --param {text!r}: use BACKEND.KEY=V1,V2,... e.g. hsv.min_area=50,100'
            raise UsageError(msg)
        if backend not in backends:
            msg = f'--param {text!r}: backend {backend!r} is not swept (add --backend {backend})'
            raise UsageError(msg)
        if key == 'device':
            msg = f'--param {text!r}: the GPU of a cell is chosen by Ray, not by a parameter'
            raise UsageError(msg)
        if (backend, key) in seen:
            msg = f'--param {backend}.{key} is given twice: list every value in one --param'
            raise UsageError(msg)
        seen.add((backend, key))
        parts = tuple(v.strip() for v in values.split(','))
        if not all(parts):
            msg = f'--param {text!r}: empty value (values are separated by commas)'
            raise UsageError(msg)
        if len(set(parts)) != len(parts):
            msg = f'--param {text!r}: a value is given twice'
            raise UsageError(msg)
        axes.append(ParamAxis(backend, key, parts))
    return tuple(axes)


def cell_options(base: BackendOptions, params: Mapping[str, str]) -> BackendOptions:
    """``base`` with a cell's parameters: typed ``BackendOptions`` fields (conf, iou, threads,
    config, model, model_family, labels, engine, precision) or else ``extra`` keys."""
    changes: dict[str, Any] = {}
    extra = dict(base.extra)
    for key, text in params.items():
        if key in _FLOAT_KEYS:
            try:
                changes[key] = float(text)
            except ValueError as err:
                msg = f'--param {key}={text!r}: expected a number'
                raise UsageError(msg) from err
        elif key == 'threads':
            if not text.isdigit() or int(text) < 1:
                msg = f'--param threads={text!r}: expected an integer >= 1'
                raise UsageError(msg)
            changes[key] = int(text)
        elif key in _PATH_KEYS:
            changes[key] = Path(text)
        elif key in _STR_KEYS:
            changes[key] = text
        else:
            extra[key] = text
    return replace(base, extra=extra, **changes)


@dataclass(frozen=True, slots=True)
class SweepSettings:
    """The run options every cell shares (the ``run`` command's options)."""

    rate: str = 'max'
    queue_depth: int = 1
    warmup: int | None = None
    threads: int | None = None
    max_frames: int | None = None
    start: float | None = None
    duration: float | None = None
    topics: tuple[str, ...] = ()
    ground_truth: str | None = None
    config: Path | None = None
    model: Path | None = None
    model_family: str | None = None
    labels: str | None = None
    conf: float | None = None
    iou: float | None = None
    engine: str = 'auto'
    precision: str = 'fp32'
    recorded_topic: str | None = None
    annotations: bool = False
    copy_images: bool = False
    report: bool = True

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready, paths as strings."""
        return {
            name: str(value)
            if isinstance(value, Path)
            else list(value)
            if isinstance(value, tuple)
            else value
            for name, value in ((n, getattr(self, n)) for n in self.__dataclass_fields__)
        }

    def backend_options(self) -> BackendOptions:
        """The options the ``run`` command would give its backends."""
        return BackendOptions(
            threads=self.threads,
            config=self.config,
            model=self.model,
            model_family=self.model_family,
            labels=self.labels,
            conf=self.conf,
            iou=self.iou,
            engine=self.engine,
            precision=self.precision,
        )


@dataclass(frozen=True, slots=True)
class InputId:
    """An input by its absolute path, size and content hash (sha256 of the file; of a folder,
    over its files' relative names, sizes and contents in name order)."""

    path: Path
    given: str
    size_bytes: int
    sha256: str


def _files_of(path: Path) -> list[Path]:
    if path.is_dir():
        return sorted(p for p in path.rglob('*') if p.is_file())
    return [path]


def input_identity(path: Path, given: str | None = None) -> InputId:
    """Size and hash of an input; SourceError when it is missing or not a file or folder."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError as err:
        msg = f'{path}: no such file or directory'
        raise SourceError(msg) from err
    except OSError as err:
        msg = f'{path}: cannot read: {err.strerror or err}'
        raise SourceError(msg) from err
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        msg = f'{path}: not a regular file or folder'
        raise SourceError(msg)
    digest = hashlib.sha256()
    size = 0
    folder = stat.S_ISDIR(mode)
    try:
        for file in _files_of(path):
            n = file.stat().st_size
            size += n
            if folder:
                digest.update(f'{file.relative_to(path).as_posix()}\0{n}\0'.encode())
            with file.open('rb') as f:
                while chunk := f.read(1 << 20):
                    digest.update(chunk)
    except OSError as err:
        msg = f'{path}: cannot read: {err.strerror or err}'
        raise SourceError(msg) from err
    return InputId(
        path.resolve(), given if given is not None else str(path), size, digest.hexdigest()
    )


@functools.cache
def _on_gpu(backend: str) -> bool:
    """Whether ``backend`` declares that it runs on a CUDA GPU (the registry's class)."""
    from replaybench.backends import get_backend
    from replaybench.backends.base import backend_traits

    return backend_traits(get_backend(backend)).device == 'cuda'


@dataclass(frozen=True, slots=True)
class Cell:
    """One (input, backend, parameter combination): one run."""

    index: int
    input_index: int
    input: InputId
    backend: str
    params: tuple[tuple[str, str], ...]
    key: str
    name: str

    @property
    def gpu(self) -> bool:
        """Whether the cell holds a GPU: its backend runs on one (``Backend.device``)."""
        return _on_gpu(self.backend)

    @property
    def params_text(self) -> str:
        """``key=value`` pairs separated by spaces ('' without parameters)."""
        return ' '.join(f'{k}={v}' for k, v in self.params)

    @property
    def column(self) -> str:
        """The sweep.html column: the backend and its parameters."""
        return f'{self.backend} {self.params_text}'.strip()


def _file_sha256(path: Path | None) -> str | None:
    if path is None or not path.is_file():
        return None
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _cell_key(
    inp: InputId, backend: str, params: Sequence[tuple[str, str]], settings: SweepSettings
) -> str:
    files = {'config': settings.config, 'model': settings.model}
    files |= {k: Path(v) for k, v in params if k in _PATH_KEYS}
    labels = settings.labels if settings.labels and settings.labels != 'coco' else None
    label_param = dict(params).get('labels', labels)
    document = {
        'replaybench': __version__,
        'input': {'size_bytes': inp.size_bytes, 'sha256': inp.sha256},
        'backend': backend,
        'params': [list(p) for p in params],
        'settings': settings.as_dict(),
        'files': {
            **{k: _file_sha256(v) for k, v in files.items()},
            'labels': _file_sha256(Path(label_param)) if label_param else None,
        },
    }
    text = json.dumps(document, sort_keys=True, separators=(',', ':'))
    return hashlib.sha256(text.encode()).hexdigest()


def _cell_name(inp: InputId, backend: str, params: Sequence[tuple[str, str]], key: str) -> str:
    stem = inp.path.name if inp.path.is_dir() else inp.path.stem
    text = '.'.join([stem, backend, *(f'{k}={v}' for k, v in params)])
    return f'{_UNSAFE.sub("_", text)[:80]}-{key[:10]}'


def plan_cells(
    inputs: Sequence[InputId],
    backends: Sequence[str],
    axes: Sequence[ParamAxis],
    settings: SweepSettings,
) -> list[Cell]:
    """Every cell, input-major: for each input, each backend with each parameter combination."""
    cells: list[Cell] = []
    for number, inp in enumerate(inputs):
        for backend in backends:
            mine = [a for a in axes if a.backend == backend]
            for combo in itertools.product(*(a.values for a in mine)):
                params = tuple((a.key, v) for a, v in zip(mine, combo, strict=True))
                key = _cell_key(inp, backend, params, settings)
                name = _cell_name(inp, backend, params, key)
                cells.append(Cell(len(cells), number, inp, backend, params, key, name))
    return cells


# --------------------------------------------------------------------------- one cell


def _run_config(
    cell: Cell, settings: SweepSettings, out_dir: Path, command: Sequence[str]
) -> RunConfig:
    """The ``RunConfig`` the ``run`` command builds for this input, backend and options
    (``replaybench.app.run.run_config``), with the cell's ``--param`` values applied."""
    from replaybench.app.run import run_config

    options = cell_options(settings.backend_options(), dict(cell.params))
    config = run_config(
        [cell.input.path],
        backends=[cell.backend],
        out=out_dir,
        rate=settings.rate,
        queue_depth=settings.queue_depth,
        warmup=settings.warmup,
        threads=options.threads,
        max_frames=settings.max_frames,
        start=settings.start,
        duration=settings.duration,
        topics=settings.topics,
        ground_truth=settings.ground_truth,
        recorded_topic=settings.recorded_topic,
        annotations=settings.annotations,
        copy_images=settings.copy_images,
        report=settings.report,
        command=command,
    )
    return replace(config, options=options)


def _check_input(inp: InputId, host: str) -> None:
    """SourceError unless the node sees the input the driver hashed (shared storage)."""
    try:
        found = input_identity(inp.path)
    except SourceError as err:
        msg = f'{inp.path} is not readable on node {host} (inputs must be on shared storage): {err}'
        raise SourceError(msg) from err
    if found.size_bytes != inp.size_bytes or found.sha256 != inp.sha256:
        msg = (
            f"{inp.path} on node {host} differs from the driver's copy "
            f'({found.size_bytes} bytes, sha256 {found.sha256[:12]} instead of '
            f'{inp.size_bytes} bytes, sha256 {inp.sha256[:12]})'
        )
        raise SourceError(msg)


def _error_line(err: BaseException) -> str:
    text = str(err) if isinstance(err, ReplaybenchError) else f'{type(err).__name__}: {err}'
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[0] if lines else type(err).__name__


def execute_cell(
    cell: Cell, settings: SweepSettings, command: Sequence[str], version: str, board: Any
) -> dict[str, Any]:
    """Run one cell where Ray placed it; the run folder's files come back as bytes."""
    import ray

    started = time.time()
    context = ray.get_runtime_context()
    where = {
        'node_id': context.get_node_id(),
        'node_ip': ray.util.get_node_ip_address(),
        'hostname': socket.gethostname(),
        'gpu_ids': [str(g) for g in ray.get_gpu_ids()],
        'pid': os.getpid(),
    }
    if board is not None:
        board.start.remote(cell.index, where['node_id'])
    report: dict[str, Any] = {'index': cell.index, 'where': where, 'started_at': started}
    try:
        if version != __version__:
            msg = f'node {where["hostname"]} has replaybench {__version__}, the driver {version}'
            raise UsageError(msg)
        _check_input(cell.input, str(where['hostname']))
        with tempfile.TemporaryDirectory(prefix='replaybench-cell-') as tmp:
            out = Path(tmp) / 'run'
            from replaybench.app.run import run_benchmark

            outcome = run_benchmark(_run_config(cell, settings, out, command))
            files = {
                p.relative_to(out).as_posix(): p.read_bytes()
                for p in sorted(out.rglob('*'))
                if p.is_file()
            }
        if outcome.status in ('complete', 'interrupted'):
            report['status'] = outcome.status
            report['files'] = files
        else:  # one backend per cell: no other status is expected
            report['status'] = 'failed'
            report['error'] = f'the run ended with status {outcome.status}'
    except Exception as err:  # noqa: BLE001  one line per failed cell; the other cells go on
        report['status'] = 'failed'
        report['error'] = _error_line(err)
    report['finished_at'] = time.time()
    return report


class _Board:
    """A Ray actor the cells tell when they start, for the progress line."""

    def __init__(self) -> None:
        self.started: dict[int, str] = {}

    def start(self, index: int, node_id: str) -> None:
        self.started[index] = node_id

    def snapshot(self) -> dict[int, str]:
        return dict(self.started)


# --------------------------------------------------------------------------- engine


def _token_available(environ: Mapping[str, str], home: Path) -> bool:
    if environ.get(_AUTH_TOKEN):
        return True
    path = environ.get(_AUTH_TOKEN_PATH)
    if path:
        return Path(path).is_file()
    return (home / '.ray' / 'auth_token').is_file()


def join_auth_env(
    address: str | None, environ: Mapping[str, str], home: Path | None = None
) -> dict[str, str]:
    """The variables to set for Ray's token authentication (Ray >= 2.60) before ``ray.init``.

    An explicit ``RAY_AUTH_MODE`` is always kept. Local instance (``address`` None): token
    authentication with ``RAY_AUTH_TOKEN`` (the given one, else a token of this process), so
    nothing is written to ``~/.ray``. Joining a cluster: token mode when a token is at hand
    (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or ``~/.ray/auth_token``), which joins
    clusters with and without authentication alike; else nothing (a cluster started without
    authentication).
    """
    if _AUTH_MODE in environ:
        return {}
    if address is None:
        if not _PROCESS_TOKEN:
            _PROCESS_TOKEN.append(secrets.token_hex(32))
        return {_AUTH_MODE: 'token', _AUTH_TOKEN: environ.get(_AUTH_TOKEN) or _PROCESS_TOKEN[0]}
    if _token_available(environ, home if home is not None else Path.home()):
        return {_AUTH_MODE: 'token'}
    return {}


@contextlib.contextmanager
def _environment(changes: Mapping[str, str]) -> Iterator[None]:
    """``os.environ`` with ``changes`` (Ray's cached auth settings refreshed), restored after."""
    before = {k: os.environ.get(k) for k in changes}
    os.environ.update(changes)
    _refresh_ray_auth(bool(changes))
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        _refresh_ray_auth(bool(changes))


def _refresh_ray_auth(changed: bool) -> None:
    """Ray reads RAY_AUTH_MODE and the token once per process; read them again."""
    if not changed:
        return
    import importlib

    raylet = importlib.import_module('ray._raylet')
    config = getattr(raylet, 'Config', None)
    loader = getattr(raylet, 'AuthenticationTokenLoader', None)
    if config is None or loader is None:  # a Ray without token authentication
        return
    config.initialize('')
    loader.instance().reset_cache()


def _import_ray() -> Any:
    try:
        with _as_found():  # importing Ray sets RAY_CLIENT_MODE
            import ray
    except ImportError as err:
        msg = "replaybench sweep needs Ray: pip install 'replaybench[sweep]'"
        raise UsageError(msg) from err
    return ray


@contextlib.contextmanager
def local_ray(
    *, num_cpus: int | None = None, temp_dir: str | None = None
) -> Iterator[dict[str, Any]]:
    """A local Ray instance for a sweep: one node slot, no dashboard, quiet logs, loopback only,
    token authentication with a token of this process; shut down on exit."""
    ray = _import_ray()
    with _environment(join_auth_env(None, os.environ)):
        try:
            context = ray.init(
                address='local',  # a new instance, never a cluster `ray start` left running
                num_cpus=num_cpus,
                resources={NODE_SLOT: 1},
                include_dashboard=False,
                logging_level=logging.ERROR,
                log_to_driver=False,
                _node_ip_address=LOCAL_NODE_IP,
                _temp_dir=temp_dir,
            )
        except Exception as err:  # Ray's start-up fails in many types: one line
            msg = f'cannot start a local Ray instance: {_error_line(err)}'
            raise EngineError(msg) from err
        try:
            yield {'mode': 'local', 'address': context.address_info.get('gcs_address')}
        finally:
            ray.shutdown()


@contextlib.contextmanager
def _joined_ray(address: str) -> Iterator[dict[str, Any]]:
    ray = _import_ray()
    changes = join_auth_env(address, os.environ)
    with _environment(changes):
        try:
            ray.init(address=address, logging_level=logging.ERROR, log_to_driver=False)
        except Exception as err:  # Ray's connection fails in many types: one line
            hint = (
                ''
                if os.environ.get(_AUTH_MODE) == 'token'
                else '; a cluster with token authentication needs its token here: set '
                "RAY_AUTH_TOKEN (or copy the head's ~/.ray/auth_token) or RAY_AUTH_MODE "
                '(docs/sweep.md)'
            )
            msg = f'cannot join the Ray cluster at {address}: {_error_line(err)}{hint}'
            raise EngineError(msg) from err
        try:
            yield {'mode': 'cluster', 'address': address}
        finally:
            ray.shutdown()


@contextlib.contextmanager
def _as_found() -> Iterator[None]:
    """``ray.init`` installs a SIGTERM handler and sets environment variables in this process:
    a sweep that started or joined Ray puts the handlers and ``os.environ`` back as it found
    them once Ray has shut down."""
    environ = dict(os.environ)
    handlers: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in handlers.items():
            if handler is not None:
                signal.signal(sig, handler)
        for key in set(os.environ) - set(environ):
            del os.environ[key]
        for key, value in environ.items():
            if os.environ.get(key) != value:
                os.environ[key] = value


@contextlib.contextmanager
def _engine(address: str | None) -> Iterator[dict[str, Any]]:
    ray = _import_ray()
    if ray.is_initialized():
        yield {'mode': 'connected', 'address': ray.get_runtime_context().gcs_address}
    elif address is not None:
        with _as_found(), _joined_ray(address) as info:
            yield info
    else:
        with _as_found(), local_ray() as info:
            yield info


def _engine_record(ray: Any, info: Mapping[str, Any], pack: bool) -> dict[str, Any]:
    nodes = []
    head = None
    for node in sorted(ray.nodes(), key=lambda n: str(n.get('NodeID'))):
        resources = {
            k: v for k, v in node.get('Resources', {}).items() if not k.startswith('node:')
        }
        if 'node:__internal_head__' in node.get('Resources', {}):
            head = node.get('NodeID')
        nodes.append(
            {
                'node_id': node.get('NodeID'),
                'ip': node.get('NodeManagerAddress'),
                'hostname': node.get('NodeManagerHostname'),
                'alive': bool(node.get('Alive')),
                'resources': resources,
            }
        )
    resources = {k: v for k, v in ray.cluster_resources().items() if not k.startswith('node:')}
    return {
        'ray_version': ray.__version__,
        'mode': info['mode'],
        'address': info.get('address'),
        'head_node_id': head,
        'resources': dict(sorted(resources.items())),
        'nodes': nodes,
        'placement': {
            'node_slot': NODE_SLOT,
            'cpu_cells': 'packed, one per CPU' if pack else 'one timed cell per node',
            'gpu_cells': 'one per GPU',
        },
        'auth_mode': os.environ.get(_AUTH_MODE, 'disabled'),
    }


# --------------------------------------------------------------------------- results


class SweepProgress(NamedTuple):
    """Cells finished (complete or failed), running and failed, out of ``total``."""

    done: int
    running: int
    failed: int
    total: int


@dataclass(frozen=True, eq=False)
class SweepResult:
    """What a sweep left in ``out``: its status, sweep.json as a dict and the cells table."""

    out: Path
    status: str  # 'complete' | 'failed' | 'interrupted'
    record: dict[str, Any]
    #: sweep.csv's rows, one mapping per cell keyed by ``CSV_COLUMNS``
    cell_rows: tuple[Mapping[str, Any], ...] = field(repr=False)

    @property
    def cells(self) -> pd.DataFrame:
        """sweep.csv as a pandas DataFrame (``pip install 'replaybench[pandas]'``)."""
        from replaybench.results.tables import records_table

        return records_table(self.cell_rows, CSV_COLUMNS)

    @property
    def exit_code(self) -> int:
        """0 complete, 1 a cell failed, 130 interrupted."""
        return {'complete': 0, 'failed': 1}.get(self.status, 130)


def _interval(values: Any) -> list[float] | None:
    from replaybench.results.bootstrap import percentile_interval

    if values is None:
        return None
    found = percentile_interval(values)
    return list(found) if found is not None else None


def cell_metrics(run_dir: Path, key: str) -> dict[str, Any]:
    """Frames, FPS, p50 and p99 latency with 95 % block-bootstrap intervals over all the cell's
    measured frames (every topic together), and mAP@0.5 (the mean over its topics)."""
    import numpy as np

    from replaybench.results.bootstrap import replicates
    from replaybench.results.intervals import measured_series
    from replaybench.results.io import read_run_result
    from replaybench.results.records import read_frames_csv
    from replaybench.results.stats import summarize

    run = read_run_result(run_dir / 'run.json')
    records = read_frames_csv(run_dir / 'frames.csv')
    rows = run.summary_rows
    if len(rows) == 1:  # one topic: the run's own figures (frames.csv rounds its times)
        only = rows[0]
        point = {
            'frames': only.measured,
            'fps': only.throughput_fps,
            'p50_ms': only.latency_ms_p50,
            'p99_ms': only.latency_ms_p99,
        }
    else:
        pooled = summarize([r._replace(topic='*') for r in records])
        summary = pooled[0] if pooled else None
        point = {
            'frames': summary.measured if summary else 0,
            'fps': summary.throughput_fps if summary else None,
            'p50_ms': summary.latency_ms_p50 if summary else None,
            'p99_ms': summary.latency_ms_p99 if summary else None,
        }
    series = measured_series(records)  # every topic together, in replay order
    seed = int(key[:16], 16)
    reps = replicates(*series, rng=np.random.default_rng(seed))
    maps = [
        row.accuracy.map50
        for row in rows
        if row.accuracy is not None and row.accuracy.map50 is not None
    ]
    return {
        'frames': point['frames'],
        'fps': point['fps'],
        'fps_ci': _interval(reps.fps) if reps is not None else None,
        'p50_ms': point['p50_ms'],
        'p50_ci': _interval(reps.p50) if reps is not None else None,
        'p99_ms': point['p99_ms'],
        'p99_ci': _interval(reps.p99) if reps is not None else None,
        'map50': float(np.mean(maps)) if maps else None,
        'topics': len({r.topic for r in records}),
    }


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        found = json.loads(path.read_text(encoding='utf-8'))
    except (OSError, ValueError):
        return None
    return found if isinstance(found, dict) else None


def _complete_cell(out: Path, cell: Cell) -> RunResult | None:
    """The run.json of a complete earlier run of this very cell, or None."""
    from replaybench.results.io import read_run_result

    path = out / CELLS_DIR / cell.name / 'run.json'
    if not path.is_file():
        return None
    try:
        run = read_run_result(path)
    except SourceError:
        return None
    if run.status != 'complete' or run.sweep is None or run.sweep.get('key') != cell.key:
        return None
    return run


def _conditions(run: RunResult, gpu: bool) -> dict[str, Any]:
    env = run.environment
    cpu = env.cpu
    section = run.sweep or {}
    gpus = env.gpus
    gpu_name = None
    if gpu and gpus:
        ids = section.get('gpu_ids') or []
        at = int(ids[0]) if ids and str(ids[0]).isdigit() and int(ids[0]) < len(gpus) else 0
        gpu_name = gpus[at].name  # the GPU Ray gave the cell, in nvidia-smi's order
    concurrency = section.get('concurrency') or {}
    return {
        'cpu': f'{cpu.model} x{cpu.logical_cores}',
        'gpu': gpu_name,
        'placement': section.get('placement'),
        'max_cells_on_node': concurrency.get('max_cells_on_node'),
    }


def _flags(entries: Sequence[dict[str, Any]]) -> None:
    """Flag complete cells measured under conditions unlike the others' (in place)."""
    done = [e for e in entries if e['status'] == 'complete']
    cpus = Counter(e['conditions']['cpu'] for e in done)
    gpus = Counter(e['conditions']['gpu'] for e in done if e['conditions']['gpu'])
    usual_cpu = cpus.most_common(1)[0][0] if cpus else None
    usual_gpu = gpus.most_common(1)[0][0] if gpus else None
    for e in done:
        c = e['conditions']
        flags: list[str] = []
        shared = c['max_cells_on_node']
        if isinstance(shared, int) and shared > 1:
            flags.append(f'shared its node with {shared - 1} other cell(s)')
        if c['placement'] == 'packed':
            flags.append('packed placement: timings not comparable')
        if len(cpus) > 1 and c['cpu'] != usual_cpu:
            flags.append(f'other CPU: {c["cpu"]} (most cells: {usual_cpu})')
        if len(gpus) > 1 and c['gpu'] and c['gpu'] != usual_gpu:
            flags.append(f'other GPU: {c["gpu"]} (most cells: {usual_gpu})')
        e['flags'] = flags


def _max_overlap(mine: tuple[float, float], others: Sequence[tuple[float, float]]) -> int:
    """Most cells running at once during ``mine`` (itself included)."""
    start, end = mine
    events = [(s, 1) for s, e in others if s < end and e > start] + [
        (e, -1) for s, e in others if s < end and e > start
    ]
    best = running = 1
    for _, step in sorted(events, key=lambda ev: (ev[0], ev[1])):
        running += step
        best = max(best, running)
    return best


def _placement(cell: Cell, pack: bool) -> str:
    if cell.gpu:
        return 'gpu'
    return 'packed' if pack else 'node-slot'


# --------------------------------------------------------------------------- the sweep


class _Sweep:
    """The driver: plans, resumes, submits, collects and writes OUT."""

    def __init__(
        self,
        out: Path,
        cells: list[Cell],
        inputs: list[InputId],
        backends: Sequence[str],
        axes: Sequence[ParamAxis],
        settings: SweepSettings,
        pack: bool,
        max_retries: int,
        command: list[str],
        progress: Callable[[SweepProgress], None] | None,
        stop: threading.Event | None = None,
    ) -> None:
        self.out = out
        self.cells = cells
        self.inputs = inputs
        self.backends = list(backends)
        self.axes = list(axes)
        self.settings = settings
        self.pack = pack
        self.max_retries = max_retries
        self.command = command
        self.progress = progress
        self.stop = stop
        self.started = dt.datetime.now(dt.UTC)
        self.t0 = time.perf_counter()
        self.status: dict[int, str] = {}
        self.errors: dict[int, str] = {}
        self.where: dict[int, dict[str, Any]] = {}
        self.times: dict[int, tuple[float, float]] = {}
        self.resumed: set[int] = set()
        self.engine: dict[str, Any] | None = None
        self.metrics: dict[int, dict[str, Any]] = {}

    # -- resume

    def prepare(self) -> list[Cell]:
        """Create OUT, keep the complete cells, return the ones to run."""
        out = self.out
        if out.exists() and not out.is_dir():
            msg = f'{out} exists and is not a directory'
            raise UsageError(msg)
        previous = out / 'sweep.json'
        if (
            out.is_dir()
            and any(out.iterdir())
            and not previous.exists()
            and not (out / CELLS_DIR).is_dir()
        ):
            msg = f'output folder {out} is not empty and holds no sweep: choose another --out'
            raise UsageError(msg)
        (out / CELLS_DIR).mkdir(parents=True, exist_ok=True)
        for stale in (out / CELLS_DIR).glob('.*.partial-*'):
            shutil.rmtree(stale, ignore_errors=True)
        earlier = _read_json(previous)
        if earlier is not None and isinstance(earlier.get('engine'), dict):
            self.engine = earlier['engine']
        todo = []
        for cell in self.cells:
            if _complete_cell(out, cell) is not None:
                self.status[cell.index] = 'complete'
                self.resumed.add(cell.index)
            else:
                self.status[cell.index] = 'pending'
                todo.append(cell)
        return todo

    # -- running

    def run(self, todo: list[Cell], address: str | None) -> bool:
        """Run ``todo`` on Ray; False when interrupted."""
        ray = _import_ray()
        # Ray prints its cluster messages (a worker that died, memory pressure) on stdout:
        # they go to stderr, stdout keeps the sweep's own output
        with contextlib.redirect_stdout(sys.stderr), _engine(address) as info:
            self.engine = _engine_record(ray, info, self.pack)
            runnable = self._feasible(todo)
            return self._loop(ray, runnable)

    def _feasible(self, todo: list[Cell]) -> list[Cell]:
        """Cells Ray can place; GPU cells on a cluster without GPUs fail at once."""
        assert self.engine is not None
        resources = self.engine['resources']
        if not self.pack and any(not c.gpu for c in todo) and not resources.get(NODE_SLOT):
            where = self.engine.get('address') or 'this Ray cluster'
            msg = (
                f'no node of the Ray cluster at {where} offers the {NODE_SLOT} resource: start '
                f'each node with --resources=\'{{"{NODE_SLOT}": 1}}\' (docs/sweep.md), or pass '
                '--pack for an accuracy-only sweep'
            )
            raise UsageError(msg)
        runnable = []
        for cell in todo:
            if cell.gpu and not resources.get('GPU'):
                self._failed(cell, 'no GPU in the Ray cluster for this GPU backend')
            else:
                runnable.append(cell)
        return runnable

    def _loop(self, ray: Any, cells: list[Cell]) -> bool:
        from ray.exceptions import RayError

        board = None
        if self.progress is not None:
            board = ray.remote(num_cpus=0)(_Board).remote()
        remote = ray.remote(max_retries=self.max_retries, retry_exceptions=False, max_calls=1)(
            execute_cell
        )
        pending: dict[Any, Cell] = {}
        for cell in cells:
            options: dict[str, Any] = {'num_cpus': 1, 'name': f'replaybench cell {cell.name}'}
            if cell.gpu:
                options['num_gpus'] = 1
            elif not self.pack:
                options['resources'] = {NODE_SLOT: 1}
            ref = remote.options(**options).remote(
                cell, self.settings, self.command, __version__, board
            )
            pending[ref] = cell
            self.status[cell.index] = 'pending'
        interrupted = False
        try:
            while pending:
                if self.stop is not None and self.stop.is_set():
                    interrupted = True
                    break
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
                for ref in ready:
                    cell = pending.pop(ref)
                    try:
                        report = ray.get(ref)
                    except RayError as err:
                        line = _error_line(err)
                        self._failed(cell, f'{line} (Ray retried {self.max_retries} time(s))')
                        continue
                    self._collect(cell, report)
                self._show(ray, board, pending)
        except KeyboardInterrupt:
            interrupted = True
        if interrupted:
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref)
            for cell in pending.values():
                self.status[cell.index] = 'interrupted'
        if board is not None:
            with contextlib.suppress(Exception):
                ray.kill(board)
        return not interrupted

    def _show(self, ray: Any, board: Any, pending: Mapping[Any, Cell]) -> None:
        if self.progress is None:
            return
        started: dict[int, str] = {}
        if board is not None:
            with contextlib.suppress(Exception):
                started = ray.get(board.snapshot.remote(), timeout=5)
        running = sum(1 for c in pending.values() if c.index in started)
        failed = sum(1 for s in self.status.values() if s == 'failed')
        done = sum(1 for s in self.status.values() if s in ('complete', 'failed'))
        self.progress(SweepProgress(done, running, failed, len(self.cells)))

    def _failed(self, cell: Cell, error: str) -> None:
        self.status[cell.index] = 'failed'
        self.errors[cell.index] = error
        self.write_outputs('running')

    def _collect(self, cell: Cell, report: Mapping[str, Any]) -> None:
        self.where[cell.index] = dict(report.get('where') or {})
        self.times[cell.index] = (float(report['started_at']), float(report['finished_at']))
        status = report.get('status')
        if status != 'complete':
            if status == 'failed':
                self._failed(cell, str(report.get('error')))
            else:
                self.status[cell.index] = 'interrupted'
            return
        self._store(cell, report['files'])
        self.status[cell.index] = 'complete'
        self.write_outputs('running')

    def _section(self, cell: Cell) -> dict[str, Any]:
        where = self.where.get(cell.index, {})
        start, end = self.times.get(cell.index, (0.0, 0.0))
        node = where.get('node_id')
        others = [
            self.times[c.index]
            for c in self.cells
            if c.index != cell.index
            and c.index in self.times
            and self.where.get(c.index, {}).get('node_id') == node
        ]
        return {
            'key': cell.key,
            'cell': cell.name,
            'backend': cell.backend,
            'params': dict(cell.params),
            'node_id': node,
            'node_ip': where.get('node_ip'),
            'hostname': where.get('hostname'),
            'gpu_ids': where.get('gpu_ids') or [],
            'placement': _placement(cell, self.pack),
            'concurrency': {
                'limit_per_node': None if cell.gpu or self.pack else 1,
                'max_cells_on_node': _max_overlap((start, end), others),
            },
            'started_at': dt.datetime.fromtimestamp(start, dt.UTC).isoformat(),
            'finished_at': dt.datetime.fromtimestamp(end, dt.UTC).isoformat(),
            'ray_version': (self.engine or {}).get('ray_version'),
        }

    def _store(self, cell: Cell, files: Mapping[str, bytes]) -> None:
        """Write the cell's folder next to its final place, then swap it in."""
        from replaybench.results.io import read_run_result, write_run_result

        cells = self.out / CELLS_DIR
        final = cells / cell.name
        tmp = cells / f'.{cell.name}.partial-{os.getpid()}'
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        for rel, data in files.items():
            target = (tmp / rel).resolve()
            if not target.is_relative_to(tmp.resolve()):
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
        run = read_run_result(tmp / 'run.json')
        write_run_result(tmp / 'run.json', replace(run, sweep=self._section(cell)))
        if final.exists():
            shutil.rmtree(final)
        tmp.rename(final)

    def finish_concurrency(self) -> None:
        """Cells run now: their run.json gets the concurrency seen over the whole sweep."""
        from replaybench.results.io import read_run_result, write_run_result

        for cell in self.cells:
            if cell.index in self.resumed or self.status.get(cell.index) != 'complete':
                continue
            path = self.out / CELLS_DIR / cell.name / 'run.json'
            if not path.is_file():
                continue
            run = read_run_result(path)
            concurrency = self._section(cell)['concurrency']
            if run.sweep is not None and run.sweep.get('concurrency') != concurrency:
                section = {**run.sweep, 'concurrency': concurrency}
                write_run_result(path, replace(run, sweep=section))

    # -- outputs

    def entries(self) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        for cell in self.cells:
            status = self.status.get(cell.index, 'pending')
            entry: dict[str, Any] = {
                'index': cell.index,
                'cell': cell.name,
                'key': cell.key,
                'input': cell.input.given,
                'input_index': cell.input_index,
                'backend': cell.backend,
                'params': dict(cell.params),
                'status': status,
                'resumed': cell.index in self.resumed,
                'error': self.errors.get(cell.index),
                'run_dir': None,
                'node_id': None,
                'hostname': None,
                'gpu_ids': [],
                'placement': _placement(cell, self.pack),
                'concurrency': None,
                'started_at': None,
                'finished_at': None,
                'metrics': None,
                'conditions': None,
                'flags': [],
            }
            where = self.where.get(cell.index)
            if where:
                entry |= {
                    'node_id': where.get('node_id'),
                    'hostname': where.get('hostname'),
                    'gpu_ids': where.get('gpu_ids') or [],
                }
            run = _complete_cell(self.out, cell) if status == 'complete' else None
            if run is not None:
                section = run.sweep or {}
                folder = self.out / CELLS_DIR / cell.name
                if cell.index not in self.metrics:
                    self.metrics[cell.index] = cell_metrics(folder, cell.key)
                entry |= {
                    'run_dir': f'{CELLS_DIR}/{cell.name}',
                    'node_id': section.get('node_id'),
                    'hostname': section.get('hostname'),
                    'gpu_ids': section.get('gpu_ids') or [],
                    'placement': section.get('placement'),
                    'concurrency': section.get('concurrency'),
                    'started_at': section.get('started_at'),
                    'finished_at': section.get('finished_at'),
                    'metrics': self.metrics[cell.index],
                    'conditions': _conditions(run, cell.gpu),
                }
            out.append(entry)
        _flags(out)
        return out

    def record(self, status: str) -> dict[str, Any]:
        entries = self.entries()
        counts = Counter(e['status'] for e in entries)
        return {
            'schema_version': SWEEP_SCHEMA_VERSION,
            'tool': {'name': 'replaybench', 'version': __version__},
            'status': status,
            'command': self.command,
            'started_at': self.started.isoformat(),
            'finished_at': dt.datetime.now(dt.UTC).isoformat(),
            'wall_s': time.perf_counter() - self.t0,
            'settings': {
                **self.settings.as_dict(),
                'backends': self.backends,
                'params': [
                    {'backend': a.backend, 'key': a.key, 'values': list(a.values)}
                    for a in self.axes
                ],
                'pack': self.pack,
                'max_retries': self.max_retries,
            },
            'engine': self.engine,
            'inputs': [
                {
                    'path': i.given,
                    'resolved': str(i.path),
                    'size_bytes': i.size_bytes,
                    'sha256': i.sha256,
                }
                for i in self.inputs
            ],
            'counts': {
                'cells': len(entries),
                'complete': counts.get('complete', 0),
                'failed': counts.get('failed', 0),
                'interrupted': counts.get('interrupted', 0),
                'pending': counts.get('pending', 0),
                'resumed': len(self.resumed),
            },
            'cells': entries,
            'outputs': {'sweep_csv': 'sweep.csv', 'sweep_html': 'sweep.html'},
        }

    def write_outputs(self, status: str) -> dict[str, Any]:
        from replaybench.report.sweep_html import render_sweep_html
        from replaybench.results.atomic import write_json_atomic, write_text_atomic

        record: dict[str, Any] = _clean(self.record(status))
        write_json_atomic(self.out / 'sweep.json', record)
        write_text_atomic(self.out / 'sweep.csv', _csv_text(csv_rows(record)))
        write_text_atomic(self.out / 'sweep.html', render_sweep_html(record))
        return record


def _clean(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def csv_rows(record: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per cell of a sweep.json record, with the ``CSV_COLUMNS``."""
    rows = []
    for e in record['cells']:
        m = e.get('metrics') or {}

        def ci(name: str, side: int, m: Mapping[str, Any] = m) -> float | None:
            found = m.get(name)
            return found[side] if found else None

        rows.append(
            {
                'cell': e['cell'],
                'input': e['input'],
                'backend': e['backend'],
                'params': ' '.join(f'{k}={v}' for k, v in e['params'].items()),
                'status': e['status'],
                'frames': m.get('frames'),
                'fps': m.get('fps'),
                'fps_low': ci('fps_ci', 0),
                'fps_high': ci('fps_ci', 1),
                'p50_ms': m.get('p50_ms'),
                'p50_low': ci('p50_ci', 0),
                'p50_high': ci('p50_ci', 1),
                'p99_ms': m.get('p99_ms'),
                'p99_low': ci('p99_ci', 0),
                'p99_high': ci('p99_ci', 1),
                'map50': m.get('map50'),
                'node': e.get('hostname') or e.get('node_id'),
                'gpu': ','.join(e.get('gpu_ids') or []),
                'concurrency': (e.get('concurrency') or {}).get('max_cells_on_node'),
                'flags': '; '.join(e.get('flags') or []),
                'error': e.get('error'),
                'run_dir': e.get('run_dir'),
                'key': e['key'],
            }
        )
    return rows


def _csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    import csv
    import io

    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(CSV_COLUMNS)
    for row in rows:
        writer.writerow(['' if row[c] is None else row[c] for c in CSV_COLUMNS])
    return buffer.getvalue()


def _check_backend_options(cells: Sequence[Cell], settings: SweepSettings) -> None:
    """UsageError for options a locally available backend refuses (before any cell runs)."""
    from replaybench.backends import get_backend

    checked: set[tuple[str, tuple[tuple[str, str], ...]]] = set()
    for cell in cells:
        if (cell.backend, cell.params) in checked:
            continue
        checked.add((cell.backend, cell.params))
        cls = get_backend(cell.backend)
        options = cell_options(settings.backend_options(), dict(cell.params))
        try:
            if not cls.available().ok:
                continue
            cls(options)  # type: ignore[call-arg]
        except ReplaybenchError as err:
            where = f' ({cell.params_text})' if cell.params else ''
            msg = f'{cell.backend}{where}: {err}'
            raise UsageError(msg) from err
        except Exception:  # noqa: BLE001  a backend that cannot be built here may still run on a node
            continue


@dataclass(frozen=True, slots=True)
class SweepConfig:
    """``replaybench sweep``'s options, checked (``sweep_config``): what ``run_sweep`` runs."""

    inputs: tuple[Path, ...]
    backends: tuple[str, ...]
    #: the sweep folder (the same one resumes)
    out: Path
    #: the ``--param`` axes, parsed
    axes: tuple[ParamAxis, ...] = ()
    #: a Ray cluster to join; None starts a local Ray instance
    address: str | None = None
    pack: bool = False
    max_retries: int = DEFAULT_MAX_RETRIES
    #: the run options every cell shares
    settings: SweepSettings = SweepSettings()
    #: the command line recorded in sweep.json
    command: tuple[str, ...] = ()


def sweep_config(
    inputs: Sequence[str | Path],
    *,
    backends: Sequence[str],
    out: str | Path,
    params: Sequence[str] = (),
    address: str | None = None,
    pack: bool = False,
    max_retries: int = DEFAULT_MAX_RETRIES,
    rate: str = 'max',
    queue_depth: int = 1,
    warmup: int | None = None,
    threads: int | None = None,
    max_frames: int | None = None,
    start: float | None = None,
    duration: float | None = None,
    topics: Sequence[str] = (),
    ground_truth: str | None = None,
    config: str | Path | None = None,
    model: str | Path | None = None,
    model_family: str | None = None,
    labels: str | None = None,
    conf: float | None = None,
    iou: float | None = None,
    engine: str = 'auto',
    precision: str = 'fp32',
    recorded_topic: str | None = None,
    annotations: bool = False,
    copy_images: bool = False,
    report: bool = True,
    command: Sequence[str] | None = None,
) -> SweepConfig:
    """The ``SweepConfig`` of ``replaybench sweep``'s options (each keyword the flag of the same
    name in snake_case; ``--param`` is ``params``, ``--topic`` is ``topics``). Raises
    ``UsageError`` naming the option for a bad value, before anything is read or run."""
    from replaybench.app.run import check_gpu_options
    from replaybench.replay.rate import parse_rate

    if not inputs:
        msg = 'no input given: name one or more bags'
        raise UsageError(msg)
    if not backends:
        msg = 'no backend given: add --backend NAME (see `replaybench backends`)'
        raise UsageError(msg)
    if len(set(backends)) != len(backends):
        msg = 'each --backend may be given once'
        raise UsageError(msg)
    if max_retries < 0:
        msg = f'--max-retries must be >= 0, not {max_retries}'
        raise UsageError(msg)
    check_gpu_options(engine, precision)
    parse_rate(rate)
    axes = parse_params(params, backends)
    settings = SweepSettings(
        rate=rate,
        queue_depth=queue_depth,
        warmup=warmup,
        threads=threads,
        max_frames=max_frames,
        start=start,
        duration=duration,
        topics=tuple(topics),
        ground_truth=ground_truth,
        config=Path(config).resolve() if config is not None else None,
        model=Path(model).resolve() if model is not None else None,
        model_family=model_family,
        labels=labels,
        conf=conf,
        iou=iou,
        engine=engine,
        precision=precision,
        recorded_topic=recorded_topic,
        annotations=annotations,
        copy_images=copy_images,
        report=report,
    )
    return SweepConfig(
        inputs=tuple(Path(i) for i in inputs),
        backends=tuple(backends),
        out=Path(out),
        axes=axes,
        address=address,
        pack=pack,
        max_retries=max_retries,
        settings=settings,
        command=tuple(command or ()),
    )


def sweep(
    inputs: Sequence[str | Path],
    *,
    backends: Sequence[str],
    out: str | Path,
    progress: Callable[[SweepProgress], None] | None = None,
    stop: threading.Event | None = None,
    **options: Any,
) -> SweepResult:
    """``run_sweep(sweep_config(inputs, backends=..., out=..., **options))``: the keyword
    arguments are ``sweep_config``'s, the ``replaybench sweep`` options."""
    config = sweep_config(inputs, backends=backends, out=out, **options)
    return run_sweep(config, progress=progress, stop=stop)


def run_sweep(
    config: SweepConfig,
    *,
    progress: Callable[[SweepProgress], None] | None = None,
    stop: threading.Event | None = None,
) -> SweepResult:
    """Run every (input, backend, ``--param`` combination) of ``config`` as one run on Ray;
    write ``config.out``.

    Without ``config.address`` a local Ray instance is started and shut down at the end (an
    already initialised Ray connection is used as it is); with it, that cluster is joined.
    Re-running with the same ``out`` resumes. Raises ``ReplaybenchError`` subclasses for an
    input that cannot be read (nothing run); a failing cell is recorded and the others go on
    (``status`` 'failed'); setting ``stop`` (the command line does on Ctrl-C and SIGTERM,
    ``replaybench.app.signals``), or a ``KeyboardInterrupt``, gives ``status`` 'interrupted'
    with the complete cells kept. No signal handler is installed.
    """
    settings = config.settings
    ids: list[InputId] = []
    for given in config.inputs:
        identity = input_identity(given, str(given))
        if any(i.path == identity.path for i in ids):
            msg = f'{given} is given twice'
            raise UsageError(msg)
        ids.append(identity)
    cells = plan_cells(ids, config.backends, config.axes, settings)
    _check_backend_options(cells, settings)
    driver = _Sweep(
        config.out,
        cells,
        ids,
        list(config.backends),
        config.axes,
        settings,
        config.pack,
        config.max_retries,
        list(config.command),
        progress,
        stop,
    )
    todo = driver.prepare()
    finished = True
    if todo:
        try:
            finished = driver.run(todo, config.address)
        finally:
            driver.finish_concurrency()
    statuses = set(driver.status.values())
    if not finished:
        status = 'interrupted'
    elif statuses - {'complete'}:
        status = 'failed'
    else:
        status = 'complete'
    record = driver.write_outputs(status)
    return SweepResult(config.out, status, record, tuple(csv_rows(record)))


# --------------------------------------------------------------------------- command line


class ProgressBar:
    """A one-line progress bar on a terminal: cells done / running / failed."""

    def __init__(self, stream: Any) -> None:
        self.stream = stream
        self.last: SweepProgress | None = None

    def __call__(self, p: SweepProgress) -> None:
        if p == self.last:
            return
        self.last = p
        filled = p.done * 25 // p.total if p.total else 25
        bar = '#' * filled + '.' * (25 - filled)
        self.stream.write(
            f'\r[{bar}] {p.done}/{p.total} cells done, {p.running} running, {p.failed} failed '
        )
        self.stream.flush()

    def close(self) -> None:
        if self.last is not None:
            self.stream.write('\n')
            self.stream.flush()


def progress_bar(stream: Any) -> ProgressBar | None:
    """A ``ProgressBar`` on ``stream`` when it is a terminal, else None."""
    isatty = getattr(stream, 'isatty', None)
    return ProgressBar(stream) if callable(isatty) and isatty() else None


def _fmt(value: Any, digits: int = 2) -> str:
    return '-' if value is None or value == '' else f'{float(value):.{digits}f}'


def result_lines(result: SweepResult) -> tuple[list[str], list[str]]:
    """What the ``sweep`` command prints: the cells table and where the outputs are (stdout),
    failed and flagged cells (stderr)."""
    rows = csv_rows(result.record)
    header = ('input', 'backend', 'params', 'status', 'fps', 'p50 ms', 'p99 ms', 'mAP@.5', 'node')
    table = [
        (
            Path(str(r['input'])).name,
            str(r['backend']),
            str(r['params']) or '-',
            str(r['status']),
            _fmt(r['fps'], 1),
            _fmt(r['p50_ms']),
            _fmt(r['p99_ms']),
            _fmt(r['map50'], 3),
            str(r['node'] or '-') + (f' gpu {r["gpu"]}' if r['gpu'] else ''),
        )
        for r in rows
    ]
    widths = [max([len(h), *(len(t[i]) for t in table)]) for i, h in enumerate(header)]
    out = [
        '  '.join(
            c.rjust(w) if 4 <= i <= 7 else c.ljust(w)
            for i, (c, w) in enumerate(zip(line, widths, strict=True))
        ).rstrip()
        for line in (header, *table)
    ]
    counts = result.record['counts']
    out.append(
        f'{counts["complete"]} of {counts["cells"]} cells complete '
        f'({counts["resumed"]} kept from an earlier run), {counts["failed"]} failed'
    )
    out.append(f'Sweep folder: {result.out}')
    out.append(f'Report: {result.out / "sweep.html"}')
    err = [
        f'replaybench: error: cell {r["cell"]} failed: {r["error"]}'
        for r in rows
        if r['status'] == 'failed'
    ]
    err += [
        f'replaybench: warning: cell {r["cell"]}: {r["flags"]}'
        for r in rows
        if r['flags'] and r['status'] == 'complete'
    ]
    if result.status == 'interrupted':
        err.append('replaybench: interrupted: complete cells are kept; run again to resume')
    return out, err
