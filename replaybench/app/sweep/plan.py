"""Planning a sweep: the ``--param`` axes, the inputs' identities and the cells with their keys.

Nothing here starts Ray or reads more than the inputs: an input is hashed here, once per sweep,
on the driver (``input_identity``: ``replaybench.sources.digest``, the digest run.json records),
and its data files' sizes and modification times travel with each cell, so that the node checks
them cheaply (``replaybench.app.sweep.cell``).
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench import _version
from replaybench.app.options import RunOptions
from replaybench.errors import ReplaybenchError, SourceError, UsageError
from replaybench.replay.instances import PATH_KEYS, split_param, with_params

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.backends.base import BackendOptions
    from replaybench.sources.digest import FileStamp

__all__ = [
    'DEFAULT_MAX_RETRIES',
    'Cell',
    'InputId',
    'ParamAxis',
    'SweepConfig',
    'cell_options',
    'check_backend_options',
    'input_identity',
    'parse_params',
    'plan_cells',
]

_UNSAFE = re.compile(r'[^A-Za-z0-9._=+-]+')


class ParamAxis(NamedTuple):
    """One ``--param LABEL.KEY=V1,V2,...``: the values one option of one backend instance
    takes (``backend``: the instance's label); one value: that instance's fixed setting."""

    backend: str
    key: str
    values: tuple[str, ...]


def parse_params(texts: Sequence[str], backends: Sequence[str]) -> tuple[ParamAxis, ...]:
    """The ``--param`` options as axes; UsageError for a malformed one or an unswept backend."""
    axes: list[ParamAxis] = []
    seen: set[tuple[str, str]] = set()
    for text in texts:
        backend, key, values = split_param(text, 'BACKEND.KEY=V1,V2,... e.g. hsv.min_area=50,100')
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


#: Ray re-runs a cell this many times when its worker or node is lost (not on errors).
DEFAULT_MAX_RETRIES = 3


@dataclass(frozen=True, slots=True)
class SweepConfig:
    """``replaybench sweep``'s options, checked (``sweep_config``): what ``run_sweep`` runs."""

    inputs: tuple[Path, ...]
    #: the backend instances by label (``--backend LABEL=NAME``, or a registered name)
    backends: tuple[str, ...]
    #: the sweep folder (the same one resumes)
    out: Path
    #: the ``--param`` axes, parsed
    axes: tuple[ParamAxis, ...] = ()
    #: a Ray cluster to join; None starts a local Ray instance
    address: str | None = None
    pack: bool = False
    max_retries: int = DEFAULT_MAX_RETRIES
    #: the run options every cell shares (``replaybench run``'s)
    options: RunOptions = field(default_factory=RunOptions)
    #: the command line recorded in sweep.json
    command: tuple[str, ...] = ()
    #: the registered backend of each instance of a label of its own (``--backend LABEL=NAME``)
    kinds: Mapping[str, str] = field(default_factory=dict)

    @property
    def backend_texts(self) -> tuple[str, ...]:
        """The ``--backend`` texts: ``LABEL=NAME`` for an instance of a label of its own."""
        return tuple(f'{b}={self.kinds[b]}' if b in self.kinds else b for b in self.backends)


def cell_options(base: BackendOptions, params: Mapping[str, str]) -> BackendOptions:
    """``base`` with a cell's parameters: typed ``BackendOptions`` fields (conf, iou, threads,
    config, model, model_family, labels, engine, precision) or else ``extra`` keys (the
    parsing ``replaybench run``'s instances share: ``replaybench.replay.instances``)."""
    return with_params(base, params)


@dataclass(frozen=True, slots=True)
class InputId:
    """An input by its absolute path, size and digest (``replaybench.sources.digest``: the
    sha256 run.json records; None with ``--no-hash``) and its data files' stamps (absolute
    path, size, modification time) for the nodes' cheap check."""

    path: Path
    given: str
    size_bytes: int
    sha256: str | None
    files: tuple[FileStamp, ...] = ()


def input_identity(path: Path, given: str | None = None, *, digest: bool = True) -> InputId:
    """Size, data files and digest of an input (``digest`` False: no digest, ``--no-hash``);
    SourceError when it is missing, not a file or folder, or no input replaybench reads."""
    from replaybench.sources.digest import data_files, file_stamps, files_sha256

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
    resolved = path.resolve()
    try:
        stamps = file_stamps([f.resolve() for f in data_files(resolved)])
        sha = files_sha256([s.path for s in stamps]) if digest else None
    except OSError as err:
        msg = f'{path}: cannot read: {err.strerror or err}'
        raise SourceError(msg) from err
    return InputId(
        resolved,
        given if given is not None else str(path),
        sum(s.size_bytes for s in stamps),
        sha,
        stamps,
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
    #: the registered backend of the instance ``backend`` names (``--backend LABEL=NAME``);
    #: '' : ``backend`` is the registered name
    kind: str = ''

    @property
    def registered(self) -> str:
        """The registered backend the cell runs (``kind``, or else ``backend``)."""
        return self.kind or self.backend

    @property
    def backend_text(self) -> str:
        """The cell's ``--backend``: ``LABEL=NAME`` for an instance of its own label."""
        return f'{self.backend}={self.kind}' if self.kind else self.backend

    @property
    def gpu(self) -> bool:
        """Whether the cell holds a GPU: its backend runs on one (``Backend.device``)."""
        return _on_gpu(self.registered)

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
    inp: InputId,
    backend: str,
    params: Sequence[tuple[str, str]],
    options: RunOptions,
    kind: str = '',
) -> str:
    files = {
        'config': options.config,
        'model': options.model,
        'ground_truth_file': options.ground_truth_file,
    }
    files |= {k: Path(v) for k, v in params if k in PATH_KEYS}
    labels = options.labels if options.labels and options.labels != 'coco' else None
    label_param = dict(params).get('labels', labels)
    # without a digest (--no-hash) the input is known by its files' sizes and times
    identity: dict[str, Any] = {'size_bytes': inp.size_bytes, 'sha256': inp.sha256}
    if inp.sha256 is None:
        identity['files'] = [[str(s.path), s.size_bytes, s.mtime_ns] for s in inp.files]
    document = {
        'replaybench': _version.__version__,
        'input': identity,
        'backend': backend,
        'params': [list(p) for p in params],
        **({'kind': kind} if kind else {}),
        'settings': options.as_dict(),
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
    options: RunOptions,
    kinds: Mapping[str, str] | None = None,
) -> list[Cell]:
    """Every cell, input-major: for each input, each backend with each parameter combination.
    ``kinds``: the registered backend of each labelled instance (``--backend LABEL=NAME``);
    a backend not in it is the registered backend of its name."""
    cells: list[Cell] = []
    for number, inp in enumerate(inputs):
        for backend in backends:
            kind = (kinds or {}).get(backend, backend)
            kind = '' if kind == backend else kind
            mine = [a for a in axes if a.backend == backend]
            for combo in itertools.product(*(a.values for a in mine)):
                params = tuple((a.key, v) for a, v in zip(mine, combo, strict=True))
                key = _cell_key(inp, backend, params, options, kind)
                name = _cell_name(inp, backend, params, key)
                cells.append(Cell(len(cells), number, inp, backend, params, key, name, kind))
    return cells


def check_backend_options(cells: Sequence[Cell], options: RunOptions) -> None:
    """UsageError for options a locally available backend refuses (before any cell runs)."""
    from replaybench.backends import get_backend

    checked: set[tuple[str, tuple[tuple[str, str], ...]]] = set()
    for cell in cells:
        if (cell.registered, cell.params) in checked:
            continue
        checked.add((cell.registered, cell.params))
        cls = get_backend(cell.registered)
        made = cell_options(options.backend_options(), dict(cell.params))
        try:
            if not cls.available().ok:
                continue
            cls(made)  # type: ignore[call-arg]
        except ReplaybenchError as err:
            where = f' ({cell.params_text})' if cell.params else ''
            msg = f'{cell.backend}{where}: {err}'
            raise UsageError(msg) from err
        except Exception:  # noqa: BLE001  a backend that cannot be built here may still run on a node
            continue
