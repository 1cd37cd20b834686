"""run.json, peak.json and comparison.json: the one place that writes them and reads them back.

``write_run_result`` / ``read_run_result`` (and the peak and comparison pairs) turn the typed
results of ``replaybench.results.model`` into indented UTF-8 JSON and back: keys in field
order, tuples as arrays, NaN and infinities as null, fields marked ``omit_none`` left out when
None. Writing is atomic (``write_json_atomic``). Reading refuses, with a ``SourceError`` naming
the file, what is not such a file: not JSON, not an object, no valid ``schema_version``, a
newer one than this replaybench knows, or a value of the wrong type (``run.json:
settings.rate: expected a string, found 3``). Keys it does not know are ignored, a field's key
of an older schema_version (``json_older`` in its metadata) is read when the key is missing,
and keys it misses take the field's default, so files of older replaybench versions still read.

With ``REPLAYBENCH_CHECK_SCHEMAS=1`` in the environment each document is also validated
against its JSON Schema (``replaybench/schemas/``) before it is written, and an
``OutputError`` says where it does not match; the check needs the ``jsonschema`` package (the
``dev`` extra) and the test suite turns it on.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import types
import typing
from collections.abc import Mapping
from importlib import resources
from pathlib import Path, PurePath
from typing import Any, TypeVar

from replaybench.errors import OutputError, SourceError
from replaybench.results.atomic import json_text, write_text_atomic
from replaybench.results.model import (
    COMPARISON_SCHEMA_VERSION,
    PEAK_SCHEMA_VERSION,
    RUN_SCHEMA_VERSION,
    Comparison,
    PeakResult,
    RunResult,
)

__all__ = [
    'CHECK_SCHEMAS_ENV',
    'check_version',
    'from_document',
    'from_json',
    'load_schema',
    'read_comparison_result',
    'read_peak_result',
    'read_run_result',
    'run_result_from_json',
    'schema_errors',
    'to_json',
    'write_comparison_result',
    'write_peak_result',
    'write_run_result',
]

#: Set to 1 to validate every written run.json, peak.json and comparison.json (needs jsonschema).
CHECK_SCHEMAS_ENV = 'REPLAYBENCH_CHECK_SCHEMAS'

_T = TypeVar('_T')

#: file name -> (model class, schema file, newest schema_version this replaybench reads)
_FILES: dict[str, tuple[type[Any], str, int]] = {
    'run.json': (RunResult, 'run.schema.json', RUN_SCHEMA_VERSION),
    'peak.json': (PeakResult, 'peak.schema.json', PEAK_SCHEMA_VERSION),
    'comparison.json': (Comparison, 'comparison.schema.json', COMPARISON_SCHEMA_VERSION),
}


# --------------------------------------------------------------------------- to JSON


def _key(f: dataclasses.Field[Any]) -> str:
    return str(f.metadata.get('json', f.name))


def to_json(value: Any) -> Any:
    """``value`` as plain JSON types: dataclasses as objects (JSON keys, field order, ``omit_none``
    fields left out when None), tuples and lists as lists, mappings with string keys, NaN and
    infinities as None, numpy scalars as Python numbers."""
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(value):
            if f.metadata.get('json_skip'):
                continue
            item = getattr(value, f.name)
            if item is None and f.metadata.get('omit_none'):
                continue
            out[_key(f)] = to_json(item)
        return out
    if isinstance(value, Mapping):
        return {str(k): to_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_json(v) for v in value]
    if isinstance(value, PurePath):
        return str(value)
    item = getattr(value, 'item', None)
    if callable(item) and type(value).__module__ == 'numpy':
        return to_json(item())
    msg = f'cannot store {type(value).__name__} in JSON'
    raise TypeError(msg)


# --------------------------------------------------------------------------- from JSON


def _kind(value: Any) -> str:
    if value is None:
        return 'null'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int | float):
        return f'the number {value!r}'
    if isinstance(value, str):
        shown = value if len(value) <= 40 else value[:37] + '...'
        return f'the string {shown!r}'
    if isinstance(value, list):
        return 'an array'
    if isinstance(value, dict):
        return 'an object'
    return type(value).__name__


def _fail(where: str, expected: str, value: Any) -> SourceError:
    return SourceError(f'{where.rstrip(":")}: expected {expected}, found {_kind(value)}')


def _at(where: str, key: object) -> str:
    """``where`` one level down: ``run.json: settings`` -> ``run.json: settings.rate``."""
    return f'{where} {key}' if where.endswith(':') else f'{where}.{key}'


@functools.cache
def _hints(cls: type[Any]) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _decode(tp: Any, value: Any, where: str, strict: bool = False) -> Any:
    if tp is Any:
        return value
    origin = typing.get_origin(tp)
    if origin is types.UnionType or origin is typing.Union:
        options = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        (inner,) = options
        return _decode(inner, value, where, strict)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise _fail(where, 'an object', value)
        return _build(typing.cast('type[Any]', tp), value, where, strict)
    if tp is bool:
        if not isinstance(value, bool):
            raise _fail(where, 'true or false', value)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(where, 'an integer', value)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise _fail(where, 'a number', value)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise _fail(where, 'a string', value)
        return value
    if origin is tuple:
        args = typing.get_args(tp)
        if not isinstance(value, list):
            raise _fail(where, 'an array', value)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_decode(args[0], v, f'{where}[{i}]', strict) for i, v in enumerate(value))
        if len(value) != len(args):
            raise _fail(where, f'an array of {len(args)}', value)
        return tuple(
            _decode(a, v, f'{where}[{i}]', strict)
            for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if origin is Mapping:
        _, inner = typing.get_args(tp)
        if not isinstance(value, dict):
            raise _fail(where, 'an object', value)
        return {str(k): _decode(inner, v, _at(where, k), strict) for k, v in value.items()}
    msg = f'{where.rstrip(":")}: no reader for {tp!r}'
    raise TypeError(msg)


def _build(cls: type[_T], data: Mapping[str, Any], where: str, strict: bool) -> _T:
    hints = _hints(typing.cast('Any', cls))
    fields = [
        f for f in dataclasses.fields(typing.cast('Any', cls)) if not f.metadata.get('json_skip')
    ]
    if strict:
        unknown = set(data) - {_key(f) for f in fields}
        if unknown:
            msg = f'{where.rstrip(":")}: no field for {", ".join(sorted(map(str, unknown)))}'
            raise TypeError(msg)
    values: dict[str, Any] = {}
    for f in fields:
        key = _key(f)
        if key not in data:
            key = f.metadata.get('json_older', key)  # the key of an older schema_version
        if key in data:
            values[f.name] = _decode(hints[f.name], data[key], _at(where, key), strict)
    return cls(**values)


def from_json(cls: type[_T], data: Any, *, where: str = '', strict: bool = False) -> _T:
    """The ``cls`` instance (a model dataclass) that the JSON value ``data`` describes.

    Missing keys take the field's default and unknown keys are ignored; a value of the wrong
    type raises ``SourceError`` naming where it is (``where`` is the prefix, e.g. the file).
    With ``strict`` (for a document built in this process, about to be written) a key the
    model has no field for raises ``TypeError`` instead of being left out.
    """
    where = f'{where or cls.__name__}:'
    if not isinstance(data, dict):
        raise _fail(where, 'an object', data)
    return _build(cls, data, where, strict)


def from_document(cls: type[_T], document: Any) -> _T:
    """The ``cls`` instance of a document built in this process (dicts, lists or tuples, NaN,
    numpy scalars): made plain JSON first (``to_json``), then read strictly (a key the model
    has no field for raises ``TypeError``, so nothing a writer puts in is left out unseen)."""
    return from_json(cls, to_json(document), where=cls.__name__, strict=True)


def run_result_from_json(data: Any, *, where: str = 'run.json') -> RunResult:
    """A RunResult from a run.json document already parsed (``from_json``)."""
    return from_json(RunResult, data, where=where)


# --------------------------------------------------------------------------- schemas


@functools.cache
def load_schema(name: str) -> dict[str, Any]:
    """The JSON Schema shipped as ``replaybench/schemas/<name>`` (e.g. ``run.schema.json``)."""
    text = resources.files('replaybench').joinpath('schemas', name).read_text(encoding='utf-8')
    schema: dict[str, Any] = json.loads(text)
    return schema


@functools.cache
def _validator(name: str) -> Any:
    import jsonschema

    schema = load_schema(name)
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)
    return cls(schema, format_checker=cls.FORMAT_CHECKER)


def schema_errors(document: Any, file: str) -> list[str]:
    """Where ``document`` breaks the schema of ``file`` (``run.json``, ``peak.json`` or
    ``comparison.json``), one line each (``at settings.rate: 3 is not of type 'string'``);
    empty when it matches. Needs the ``jsonschema`` package."""
    validator = _validator(_FILES[file][1])
    found = []
    for error in sorted(validator.iter_errors(document), key=lambda e: list(e.absolute_path)):
        path = '.'.join(str(p) for p in error.absolute_path) or '(top level)'
        found.append(f'at {path}: {error.message}')
    return found


def _check_schema(document: Any, file: str, path: Path) -> None:
    if os.environ.get(CHECK_SCHEMAS_ENV, '') in ('', '0'):
        return
    errors = schema_errors(document, file)
    if errors:
        msg = f'{path}: does not match {_FILES[file][1]}: {"; ".join(errors[:5])}'
        raise OutputError(msg)


# --------------------------------------------------------------------------- files


def _write(path: str | Path, result: Any, file: str) -> dict[str, Any]:
    document: dict[str, Any] = to_json(result)
    _check_schema(document, file, Path(path))
    write_text_atomic(path, json_text(document))
    return document


def write_run_result(path: str | Path, result: RunResult) -> dict[str, Any]:
    """Write run.json (atomically); returns the JSON document written."""
    return _write(path, result, 'run.json')


def write_peak_result(path: str | Path, result: PeakResult) -> dict[str, Any]:
    """Write peak.json (atomically); returns the JSON document written."""
    return _write(path, result, 'peak.json')


def write_comparison_result(path: str | Path, comparison: Comparison) -> dict[str, Any]:
    """Write comparison.json (atomically); returns the JSON document written."""
    return _write(path, comparison, 'comparison.json')


def _read(path: str | Path, file: str) -> tuple[Any, Path]:
    """The checked JSON document of ``file`` at ``path`` (the file, or the folder holding it)."""
    path = Path(path)
    target = path / file if path.is_dir() else path
    try:
        text = target.read_text(encoding='utf-8')
    except FileNotFoundError as err:
        msg = f'{target}: no such file'
        raise SourceError(msg) from err
    except (OSError, UnicodeDecodeError) as err:
        msg = f'{target}: cannot read: {err}'
        raise SourceError(msg) from err
    try:
        document = json.loads(text)
    except json.JSONDecodeError as err:
        msg = f'{target}: invalid JSON at line {err.lineno} column {err.colno}: {err.msg}'
        raise SourceError(msg) from err
    if not isinstance(document, dict):
        msg = f'{target}: expected a JSON object, found {type(document).__name__}'
        raise SourceError(msg) from None
    check_version(document, target, file)
    return document, target


def check_version(document: Mapping[str, Any], target: Path, file: str) -> None:
    """SourceError unless ``document`` has a ``schema_version`` this replaybench reads."""
    newest = _FILES[file][2]
    version = document.get('schema_version')
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        msg = f'{target}: missing or invalid schema_version {version!r}'
        raise SourceError(msg) from None
    if version > newest:
        msg = (
            f'{target}: schema_version {version} is newer than this replaybench supports '
            f'({newest}); upgrade replaybench to read it'
        )
        raise SourceError(msg) from None


def read_run_result(path: str | Path) -> RunResult:
    """run.json of a run folder (``path`` is the folder or the file) as a RunResult."""
    document, target = _read(path, 'run.json')
    return from_json(RunResult, document, where=str(target))


def read_peak_result(path: str | Path) -> PeakResult:
    """peak.json of a peak folder (``path`` is the folder or the file) as a PeakResult."""
    document, target = _read(path, 'peak.json')
    if document.get('kind') != 'peak':
        msg = f'{target}: not a peak.json (expected an object with "kind": "peak")'
        raise SourceError(msg)
    return from_json(PeakResult, document, where=str(target))


def read_comparison_result(path: str | Path) -> Comparison:
    """comparison.json (``path`` is the file or the folder holding it) as a Comparison."""
    document, target = _read(path, 'comparison.json')
    return from_json(Comparison, document, where=str(target))
