"""The sha256 of an input, defined once: run.json and sweep.json record this value.

An input's digest is the sha256 of its data files (``Source.files``: the ``.mcap``, ``.bag`` or
``.db3`` file, or a rosbag2 folder's storage files in replay order) read as one stream, file
after file; file names, ``metadata.yaml`` and write-ahead logs are not part of it. The run
(``replaybench.replay.hashing.InputHash``) and the sweep (``replaybench.app.sweep``) both call
``files_sha256``, so the two files agree for files and folders alike.

``file_stamps`` is the cheap identity a sweep node checks first: each data file's size and
modification time; only where they disagree with the driver's is the digest computed again.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, NamedTuple, Protocol

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

__all__ = [
    'CHUNK_BYTES',
    'FileStamp',
    'HashCancelled',
    'data_files',
    'file_stamps',
    'files_sha256',
    'input_sha256',
]

#: Bytes read and digested at a time; hashlib releases the GIL for buffers this large.
CHUNK_BYTES = 1 << 20


class Digest(Protocol):
    """What ``files_sha256`` needs of a hash object (``hashlib.sha256()``)."""

    def update(self, data: bytes, /) -> None: ...

    def hexdigest(self) -> str: ...


class HashCancelled(Exception):  # noqa: N818 - a request, not an error
    """``files_sha256`` stopped because ``cancelled()`` became true."""


class FileStamp(NamedTuple):
    """One data file of an input: its path, size and modification time (ns)."""

    path: Path
    size_bytes: int
    mtime_ns: int


def data_files(path: Path) -> list[Path]:
    """The data files of the input at ``path``, in the order its source reads them
    (``Source.files``): a bag file is its own data file; a rosbag2 folder is opened
    (``replaybench.sources.open_source``; ``SourceError`` when it cannot be)."""
    from replaybench.sources import open_source

    if path.is_file() and path.name != 'metadata.yaml':
        return [path]
    with open_source(path) as source:
        return list(source.files)


def file_stamps(files: Sequence[Path]) -> tuple[FileStamp, ...]:
    """Size and modification time of each file (``OSError`` when one cannot be read)."""
    found = []
    for file in files:
        st = file.stat()
        found.append(FileStamp(file, st.st_size, st.st_mtime_ns))
    return tuple(found)


def files_sha256(
    files: Sequence[Path],
    *,
    digest: Callable[[], Digest] = hashlib.sha256,
    chunk_bytes: int = CHUNK_BYTES,
    cancelled: Callable[[], bool] | None = None,
) -> str:
    """The sha256 (hex) of ``files`` read one after another as one stream: THE digest of an
    input. ``OSError`` when a file cannot be read; ``HashCancelled`` when ``cancelled()``
    becomes true between two chunks."""
    state = digest()
    for path in files:
        with path.open('rb') as f:
            while chunk := f.read(chunk_bytes):
                if cancelled is not None and cancelled():
                    raise HashCancelled
                state.update(chunk)
    return state.hexdigest()


def input_sha256(path: Path) -> str:
    """The digest of the input at ``path`` (a file or a rosbag2 folder): ``files_sha256`` of
    its ``data_files``."""
    return files_sha256(data_files(path))
