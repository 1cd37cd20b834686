"""Files written whole or not at all: text and JSON through a temporary file in the same
folder and ``os.replace``."""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path, PurePath
from typing import Any

from replaybench.results.runfolder import with_filename

__all__ = ['json_text', 'write_json_atomic', 'write_text_atomic']


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
