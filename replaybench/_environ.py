"""``os.environ`` left as it was found: libraries that set variables when they load
(threadpoolctl sets ``KMP_DUPLICATE_LIB_OK``, OpenCV's loader extends ``LD_LIBRARY_PATH``) are
imported, and library calls run, inside ``kept_environ``."""

from __future__ import annotations

import contextlib
import os
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = ['kept_environ']


@contextlib.contextmanager
def kept_environ() -> Iterator[None]:
    """Inside the block ``os.environ`` may change; when it ends, however it ends, every
    variable added is removed and every one changed or removed is put back."""
    before = dict(os.environ)
    try:
        yield
    finally:
        after = dict(os.environ)
        if after != before:
            for name in after.keys() - before.keys():
                del os.environ[name]
            for name, value in before.items():
                if after.get(name) != value:
                    os.environ[name] = value
