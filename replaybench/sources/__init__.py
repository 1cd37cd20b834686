"""Containers -> raw messages in a deterministic replay order.

``open_source(path)`` opens an MCAP file, a rosbag2 directory or ``.db3`` file, or a ROS 1
``.bag``, read-only, and returns a :class:`Source`. Messages come in log-time order; equal
log times are ordered by topic name, then by their order in the file(s).
``RawMessage.seq`` is the index of a message within its topic over the whole input, so it
does not change with the ``topics`` / ``start_ns`` / ``end_ns`` filters.

Readers are imported only when a file of their kind is opened.
"""

from __future__ import annotations

import stat
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from replaybench.errors import SourceError

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterator
    from types import TracebackType
    from typing import Self

    from replaybench.types import RawMessage, SkippedTopic, TopicInfo

__all__ = ['STORAGE_PLUGINS', 'Source', 'open_source']


class Source(Protocol):
    """An opened container."""

    path: Path
    format: str  #: 'mcap' | 'rosbag2' | 'rosbag1'
    files: list[Path]  #: the data files

    @property
    def truncated(self) -> bool:
        """True once the reader found the file cut short."""
        ...

    @property
    def warnings(self) -> list[str]:
        """Human-readable lines (truncation, skipped records)."""
        ...

    def topics(self) -> list[TopicInfo]:
        """Topics sorted by name."""
        ...

    def skipped_topics(self) -> list[SkippedTopic]:
        """Topics held in an encoding that cannot be read (not in ``topics``), sorted by name."""
        ...

    def messages(
        self,
        topics: Collection[str] | None = None,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[RawMessage]:
        """Messages in replay order; log time ``start_ns`` inclusive, ``end_ns`` exclusive."""
        ...

    def close(self) -> None:
        """Release the files."""
        ...

    def __enter__(self) -> Self: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...


def _open_mcap(path: Path) -> Source:
    from .mcap import McapSource

    return McapSource(path)


def _open_rosbag2(path: Path) -> Source:
    from .rosbag2 import open_rosbag2

    return open_rosbag2(path)


def _open_rosbag1(path: Path) -> Source:
    from .rosbag1 import Rosbag1Source

    return Rosbag1Source(path)


#: Readers keyed by file suffix; ``''`` is a rosbag2 directory.
STORAGE_PLUGINS: dict[str, Callable[[Path], Source]] = {
    '.mcap': _open_mcap,
    '.db3': _open_rosbag2,
    '.bag': _open_rosbag1,
    '': _open_rosbag2,
}

_MAGICS: tuple[tuple[bytes, str], ...] = (
    (b'\x89MCAP0\r\n', '.mcap'),
    (b'#ROSBAG V2.0\n', '.bag'),
    (b'SQLite format 3\x00', '.db3'),
)
_KIND_NAMES = {'.mcap': 'an MCAP file', '.bag': 'a ROS 1 bag', '.db3': 'a rosbag2 .db3 file'}


def _sniff(path: Path, head: bytes) -> str:
    """The STORAGE_PLUGINS key for a file's content; SourceError when it is none of them."""
    for magic, key in _MAGICS:
        if head.startswith(magic):
            return key
    expected = _KIND_NAMES.get(path.suffix.lower())
    if head.startswith(b'#ROSBAG V'):
        version = head[9:].split(b'\n', 1)[0].decode('latin-1', 'replace')
        msg = f'{path}: ROS bag version {version} is not supported (only 2.0)'
    elif head.startswith(b'\x28\xb5\x2f\xfd'):
        msg = f'{path}: zstd-compressed file; open the rosbag2 directory that holds it'
    elif expected:
        msg = f'{path}: not {expected} (its first bytes are not the expected magic)'
    else:
        msg = f'{path}: unrecognised format (not MCAP, ROS 1 bag, rosbag2 directory or .db3)'
    raise SourceError(msg)


#: What a path that is neither a regular file nor a directory is, by ``stat`` type.
_SPECIAL_KINDS: tuple[tuple[Callable[[int], bool], str], ...] = (
    (stat.S_ISFIFO, 'a FIFO'),
    (stat.S_ISCHR, 'a character device'),
    (stat.S_ISBLK, 'a block device'),
    (stat.S_ISSOCK, 'a socket'),
)


def _refuse_special(path: Path) -> None:
    """SourceError when ``path`` is not a regular file or directory (checked before opening).

    Opening a FIFO with no writer blocks forever and a device reads without end or nothing
    at all, so their kind is named instead of their content being read.
    """
    mode = path.stat().st_mode
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return
    kind = next((name for test, name in _SPECIAL_KINDS if test(mode)), 'a special file')
    msg = f'{path}: is {kind}, not a regular file; give a bag file or a rosbag2 folder'
    raise SourceError(msg)


def open_source(path: str | Path) -> Source:
    """Open a container read-only; SourceError (one line) when it cannot be read.

    Files are recognised by their magic bytes (the suffix only names what was expected);
    directories must be rosbag2 bags: with a ``metadata.yaml``, or without one (a recording that
    was not closed) holding one storage file or the files of one split bag. FIFOs, devices and
    sockets are refused before they are opened.
    """
    path = Path(path).expanduser()
    if path.name == 'metadata.yaml' and path.is_file():
        path = path.parent
    try:
        if path.is_dir():
            key = ''  # a rosbag2 bag; without metadata.yaml, its storage files (rosbag2.py)
        elif not path.exists():
            msg = f'{path}: no such file or directory'
            raise SourceError(msg)
        else:
            _refuse_special(path)
            with path.open('rb') as handle:
                head = handle.read(16)
            if not head:
                msg = f'{path}: file is empty'
                raise SourceError(msg)
            key = _sniff(path, head)
        return STORAGE_PLUGINS[key](path)
    except SourceError:
        raise
    except OSError as err:
        msg = f'{path}: cannot read: {err.strerror or err}'
        raise SourceError(msg) from err
    except Exception as err:
        text = ' '.join(str(err).split()) or type(err).__name__
        msg = f'{path}: cannot read ({type(err).__name__}: {text})'
        raise SourceError(msg) from err
