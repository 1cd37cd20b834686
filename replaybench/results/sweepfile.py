"""sweep.json as a typed, frozen model: written and read here, as run.json is in ``io``.

``SweepRecord`` is what ``replaybench sweep`` leaves in its folder (schema
``replaybench/schemas/sweep.schema.json``, docs/sweep.md): the Ray engine, the inputs and one
``SweepCell`` per (input, backend, parameter combination). The run options every cell shares
are kept by name in ``SweepSettings.options`` and stored beside the sweep's own settings in
the file's ``settings`` object (``replaybench.app.options.RunOptions`` types them).

``write_sweep_result`` writes the file atomically (checked against its schema when
``REPLAYBENCH_CHECK_SCHEMAS=1``, as the other files are); ``read_sweep_result`` reads it back
(``SourceError`` naming the file for what is not a sweep.json of a known version).
"""

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from replaybench.errors import OutputError, SourceError
from replaybench.results.model import Tool

__all__ = [
    'SWEEP_SCHEMA_VERSION',
    'CellConcurrency',
    'CellConditions',
    'CellMetrics',
    'EngineNode',
    'EnginePlacement',
    'SweepAxis',
    'SweepCell',
    'SweepCounts',
    'SweepEngine',
    'SweepInput',
    'SweepOutputs',
    'SweepRecord',
    'SweepSettings',
    'read_sweep_result',
    'sweep_document',
    'write_sweep_result',
]

#: Version of the sweep.json layout; readers refuse files with a newer one.
SWEEP_SCHEMA_VERSION = 1
_FILE = 'sweep.json'


def _empty() -> dict[str, Any]:
    return {}


@dataclass(frozen=True, slots=True)
class SweepAxis:
    """One ``--param``: the values one option of one backend takes."""

    backend: str = ''
    key: str = ''
    values: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class SweepSettings:
    """The sweep's own options and (``options``) the run options every cell shares, by name."""

    backends: tuple[str, ...] = ()
    params: tuple[SweepAxis, ...] = ()
    pack: bool = False
    max_retries: int = 0
    #: ``RunOptions`` as JSON values; in the file, keys of ``settings`` itself
    options: Mapping[str, Any] = field(default_factory=_empty)


@dataclass(frozen=True, slots=True)
class EngineNode:
    """A node of the Ray cluster when the sweep started its cells."""

    node_id: str = ''
    ip: str | None = None
    hostname: str | None = None
    alive: bool = False
    resources: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class EnginePlacement:
    """How cells were placed: the node-slot resource honoured and the rule per kind of cell."""

    node_slot: str = ''
    cpu_cells: str = ''
    gpu_cells: str = ''


@dataclass(frozen=True, slots=True)
class SweepEngine:
    """The Ray engine of the last invocation that ran cells."""

    ray_version: str = ''
    mode: str = 'local'  # 'local' | 'cluster' | 'connected'
    address: str | None = None
    head_node_id: str | None = None
    resources: Mapping[str, float] = field(default_factory=dict)
    nodes: tuple[EngineNode, ...] = ()
    placement: EnginePlacement = EnginePlacement()
    auth_mode: str = 'disabled'


@dataclass(frozen=True, slots=True)
class SweepInput:
    """One input: as given, resolved, its data files' size and their sha256 (the digest
    run.json records; null with ``--no-hash``)."""

    path: str = ''
    resolved: str = ''
    size_bytes: int = 0
    sha256: str | None = None


@dataclass(frozen=True, slots=True)
class SweepCounts:
    """Cells by status, and how many were kept from an earlier invocation."""

    cells: int = 0
    complete: int = 0
    failed: int = 0
    interrupted: int = 0
    pending: int = 0
    resumed: int = 0


@dataclass(frozen=True, slots=True)
class CellConcurrency:
    """At most this many cells per node (None: no limit) and the most seen on the cell's node
    while it ran (itself included)."""

    limit_per_node: int | None = None
    max_cells_on_node: int = 1


@dataclass(frozen=True, slots=True)
class CellMetrics:
    """A complete cell's figures over all its measured frames, with 95 % intervals, and the
    tasks' metrics the sweep shows (``values``).

    ``values`` maps each metric with ``MetricSpec.sweep`` (``replaybench.tasks``) to the mean
    over the cell's topics that have it, None where none has (a backend of another task), in
    sweep.csv's order. In sweep.json they are keys of the cell's ``metrics`` object beside the
    common ones (``_TOPICS_AT``). ``metrics.map50`` and the like still read a value the cell
    holds by name (a cell recorded by this version holds every sweep metric, None or not);
    ``value(name)`` is None for one it does not hold (a sweep.json of an earlier version).
    """

    frames: int = 0
    fps: float | None = None
    fps_ci: tuple[float, float] | None = None
    p50_ms: float | None = None
    p50_ci: tuple[float, float] | None = None
    p99_ms: float | None = None
    p99_ci: tuple[float, float] | None = None
    topics: int = 0
    values: Mapping[str, float | None] = field(default_factory=dict)

    def value(self, name: str) -> float | None:
        """The value of the sweep metric ``name``; None where the cell has none."""
        return self.values.get(name)

    def __getattr__(self, name: str) -> float | None:
        # ``metrics.map50``: a value by name, as when each metric was a field of its own
        if name.startswith('_') or name == 'values':
            raise AttributeError(name)
        values = self.values
        if name in values:
            return values[name]
        held = ', '.join(values) or 'none'
        msg = f'CellMetrics has no attribute or sweep metric {name!r} (metrics held: {held})'
        raise AttributeError(msg)


#: The common keys of a cell's ``metrics`` in sweep.json; the sweep metrics' values are the
#: others, and ``topics`` is written as the ``_TOPICS_AT``-th key: after the first sweep metric,
#: where the first sweep.json files had it (the later metrics were added after it).
_COMMON_METRIC_KEYS = tuple(f.name for f in fields(CellMetrics) if f.name != 'values')
_TOPICS_AT = 8


@dataclass(frozen=True, slots=True)
class CellConditions:
    """What a cell was measured on, to flag cells unlike the others."""

    cpu: str = ''
    gpu: str | None = None
    placement: str | None = None
    max_cells_on_node: int | None = None


@dataclass(frozen=True, slots=True)
class SweepCell:
    """One cell: its run (``run_dir``, relative to the sweep folder) and what it measured."""

    index: int = 0
    cell: str = ''
    key: str = ''
    input: str = ''
    input_index: int = 0
    backend: str = ''
    params: Mapping[str, str] = field(default_factory=dict)
    status: str = 'pending'  # 'complete' | 'failed' | 'interrupted' | 'pending'
    resumed: bool = False
    error: str | None = None
    run_dir: str | None = None
    node_id: str | None = None
    hostname: str | None = None
    gpu_ids: tuple[str, ...] = ()
    placement: str = 'node-slot'  # 'node-slot' | 'gpu' | 'packed'
    concurrency: CellConcurrency | None = None
    started_at: str | None = None
    finished_at: str | None = None
    metrics: CellMetrics | None = None
    conditions: CellConditions | None = None
    flags: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class SweepOutputs:
    """The sweep folder's other files."""

    sweep_csv: str = 'sweep.csv'
    sweep_html: str = 'sweep.html'


@dataclass(frozen=True, slots=True)
class SweepRecord:
    """sweep.json (docs/sweep.md)."""

    schema_version: int = SWEEP_SCHEMA_VERSION
    tool: Tool = field(default_factory=Tool)
    status: str = 'running'  # 'complete' | 'failed' | 'interrupted' | 'running'
    command: tuple[str, ...] = ()
    started_at: str = ''
    finished_at: str = ''
    wall_s: float = 0.0
    settings: SweepSettings = SweepSettings()
    engine: SweepEngine | None = None
    inputs: tuple[SweepInput, ...] = ()
    counts: SweepCounts = SweepCounts()
    cells: tuple[SweepCell, ...] = ()
    outputs: SweepOutputs = SweepOutputs()


_SETTINGS_KEYS = tuple(f.name for f in fields(SweepSettings) if f.name != 'options')


def sweep_document(record: SweepRecord) -> dict[str, Any]:
    """``record`` as the JSON document sweep.json holds (the run options flat in
    ``settings``)."""
    from replaybench.results.io import to_json

    document: dict[str, Any] = to_json(record)
    settings = document['settings']
    options = settings.pop('options')
    document['settings'] = {**options, **settings}
    for cell in document['cells']:
        if cell['metrics'] is not None:
            cell['metrics'] = _flat_metrics(cell['metrics'])
    return document


def _flat_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """A cell's ``metrics`` as sweep.json holds them: the common keys and the sweep metrics'
    values side by side, ``topics`` at ``_TOPICS_AT``."""
    values = metrics.pop('values')
    topics = metrics.pop('topics')
    items = [*metrics.items(), *values.items()]
    items.insert(min(_TOPICS_AT, len(items)), ('topics', topics))
    return dict(items)


def _nested_metrics(metrics: Any) -> Any:
    """A cell's ``metrics`` of sweep.json as ``CellMetrics`` reads them: the keys that are no
    common key are the sweep metrics' values (a file of any version: each holds what it had)."""
    if not isinstance(metrics, dict):
        return metrics  # null, or something from_json names as wrong
    common = {k: v for k, v in metrics.items() if k in _COMMON_METRIC_KEYS}
    return {**common, 'values': {k: v for k, v in metrics.items() if k not in common}}


def _record(document: Any, where: str) -> SweepRecord:
    from replaybench.results.io import from_json

    if not isinstance(document, dict):
        msg = f'{where}: expected a JSON object, found {type(document).__name__}'
        raise SourceError(msg)
    settings = document.get('settings')
    if isinstance(settings, dict):
        mine = {k: v for k, v in settings.items() if k in _SETTINGS_KEYS}
        options = {k: v for k, v in settings.items() if k not in _SETTINGS_KEYS}
        document = {**document, 'settings': {**mine, 'options': options}}
    cells = document.get('cells')
    if isinstance(cells, list):
        cells = [
            {**c, 'metrics': _nested_metrics(c['metrics'])}
            if isinstance(c, dict) and 'metrics' in c
            else c
            for c in cells
        ]
        document = {**document, 'cells': cells}
    return from_json(SweepRecord, document, where=where)


def _check_schema(document: Mapping[str, Any], path: Path) -> None:
    from replaybench.results.io import CHECK_SCHEMAS_ENV, load_schema

    if os.environ.get(CHECK_SCHEMAS_ENV, '') in ('', '0'):
        return
    import jsonschema

    schema = load_schema('sweep.schema.json')
    cls = jsonschema.validators.validator_for(schema)
    validator = cls(schema, format_checker=cls.FORMAT_CHECKER)
    errors = [
        f'at {".".join(str(p) for p in e.absolute_path) or "(top level)"}: {e.message}'
        for e in sorted(validator.iter_errors(document), key=lambda e: list(e.absolute_path))
    ]
    if errors:
        msg = f'{path}: does not match sweep.schema.json: {"; ".join(errors[:5])}'
        raise OutputError(msg)


def write_sweep_result(path: str | Path, record: SweepRecord) -> dict[str, Any]:
    """Write sweep.json (atomically); returns the JSON document written."""
    from replaybench.results.atomic import write_text_atomic

    document = sweep_document(record)  # JSON values only: NaN and infinities are null
    _check_schema(document, Path(path))
    write_text_atomic(path, json.dumps(document, indent=2, allow_nan=False) + '\n')
    return document


def read_sweep_result(path: str | Path) -> SweepRecord:
    """sweep.json of a sweep folder (``path`` is the folder or the file) as a SweepRecord."""
    path = Path(path)
    target = path / _FILE if path.is_dir() else path
    try:
        document = json.loads(target.read_text(encoding='utf-8'))
    except FileNotFoundError as err:
        msg = f'{target}: no such file'
        raise SourceError(msg) from err
    except (OSError, UnicodeDecodeError) as err:
        msg = f'{target}: cannot read: {err}'
        raise SourceError(msg) from err
    except json.JSONDecodeError as err:
        msg = f'{target}: invalid JSON at line {err.lineno} column {err.colno}: {err.msg}'
        raise SourceError(msg) from err
    version = document.get('schema_version') if isinstance(document, dict) else None
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        msg = f'{target}: missing or invalid schema_version {version!r}'
        raise SourceError(msg)
    if version > SWEEP_SCHEMA_VERSION:
        msg = (
            f'{target}: schema_version {version} is newer than this replaybench supports '
            f'({SWEEP_SCHEMA_VERSION}); upgrade replaybench to read it'
        )
        raise SourceError(msg)
    return _record(document, str(target))
