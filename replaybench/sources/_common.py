"""Helpers shared by the container readers: type names, decompression, read-only mapping."""

from __future__ import annotations

import contextlib
import mmap
import os
from typing import TYPE_CHECKING, Any

from replaybench.errors import SourceError

if TYPE_CHECKING:
    from pathlib import Path

__all__ = [
    'MAX_CHUNK_BYTES',
    'MappedFile',
    'decompress',
    'decompress_chunk',
    'decompress_message',
    'decompress_partial',
    'normalize_msgtype',
    'normalize_topic',
    'zero_tail_start',
]


def normalize_msgtype(name: str) -> str:
    """ROS 2 spelling of a message type name.

    ``sensor_msgs/Image`` (ROS 1) and ``sensor_msgs::msg::Image`` (IDL) both become
    ``sensor_msgs/msg/Image``; names already in ROS 2 spelling are returned unchanged.
    """
    parts = [part for part in name.strip().replace('::', '/').split('/') if part]
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    return '/'.join(parts)


def normalize_topic(name: str) -> str:
    """Topic name with repeated slashes collapsed, as rosbags spells ROS 1 topics."""
    if not name:
        return name
    lead = '/' if name[0] == '/' else ''
    return lead + '/'.join(part for part in name.split('/') if part)


#: Largest uncompressed chunk accepted: a corrupted size field must not make us allocate more.
MAX_CHUNK_BYTES = 1 << 30


def _check_size(size: int) -> None:
    if not 0 <= size <= MAX_CHUNK_BYTES:
        msg = f'declared uncompressed size {size} is beyond the {MAX_CHUNK_BYTES}-byte limit'
        raise ValueError(msg)


def decompress(data: memoryview, compression: str, size: int) -> bytes:
    """Decompress one whole chunk; ``size`` is its declared uncompressed size.

    Never produces (or allocates for) more than ``size`` bytes; a stream that holds more or
    less than declared is an error.
    """
    _check_size(size)
    if compression == 'zstd':
        import zstandard

        claimed = zstandard.frame_content_size(data)
        if claimed > size:  # -1 when the frame does not say
            msg = f'zstd frame claims {claimed} bytes, the chunk {size}'
            raise ValueError(msg)
        out = bytes(zstandard.ZstdDecompressor().decompress(data, max_output_size=size))
    elif compression == 'lz4':
        import lz4.frame

        out = bytes(lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1))
    elif compression == 'bz2':
        import bz2

        out = bz2.BZ2Decompressor().decompress(data, max_length=size + 1)
    else:
        msg = f'compression {compression!r} is not supported'
        raise ValueError(msg)
    if len(out) != size:
        held = 'more' if len(out) > size else str(len(out))
        msg = f'{compression} chunk holds {held} bytes, not {size}'
        raise ValueError(msg)
    return out


def decompress_chunk(
    view: memoryview, start: int, length: int, compression: str, size: int, *, partial: bool
) -> bytes:
    """Decompress the chunk at ``view[start:start + length]`` (``partial``: its end is missing).

    Every failure is a ValueError; the slice of ``view`` is released either way.
    """
    raw = view[start : start + length]
    try:
        if partial:
            return decompress_partial(raw, compression, size)
        return decompress(raw, compression, size)
    except ValueError:
        raise
    except Exception as err:  # the codecs raise their own error types
        msg = f'{type(err).__name__}: {err}'
        raise ValueError(msg) from err
    finally:
        raw.release()


def decompress_message(
    data: bytes | memoryview, limit: int | None = None, dctx: Any = None
) -> bytes:
    """Decompress one zstd-compressed message (rosbag2 ``compression_mode: message``).

    Unlike a chunk, a message declares no size outside its frame, so the frame is held to
    ``limit`` (default ``MAX_CHUNK_BYTES``): a frame header claiming more is refused before
    anything is allocated, and a frame without a size is decompressed into at most ``limit``
    bytes and refused when it holds more. ``dctx``: a ``zstandard.ZstdDecompressor`` to reuse
    across the messages of one stream (one thread); a new one when None.
    """
    import zstandard

    cap = MAX_CHUNK_BYTES if limit is None else limit
    try:
        claimed = zstandard.frame_content_size(data)
    except zstandard.ZstdError as err:
        msg = f'not a zstd frame ({err})'
        raise ValueError(msg) from err
    if claimed > cap:
        msg = f'zstd frame claims {claimed} bytes, beyond the {cap}-byte limit'
        raise ValueError(msg)
    if dctx is None:
        dctx = zstandard.ZstdDecompressor()
    try:
        if claimed >= 0:  # checked against the header: a frame cut short is an error
            return bytes(dctx.decompress(data))
        with dctx.stream_reader(data) as reader:  # bounded: never more than cap + 1 bytes
            held = len(reader.read(cap + 1))
        if held > cap:
            msg = f'zstd frame holds more than the {cap}-byte limit'
            raise ValueError(msg)
        stream = dctx.decompressobj()
        out = stream.decompress(data)  # at most the ``held`` bytes just counted
    except zstandard.ZstdError as err:
        msg = f'zstd: {err}'
        raise ValueError(msg) from err
    if not stream.eof:
        msg = 'zstd: frame cut short'
        raise ValueError(msg)
    return bytes(out)


def decompress_partial(data: memoryview, compression: str, size: int) -> bytes:
    """Decompress as much as possible (at most ``size`` bytes) of a chunk whose end is missing."""
    _check_size(size)
    if compression == 'zstd':
        import zstandard

        try:
            claimed = zstandard.frame_content_size(data)
        except zstandard.ZstdError:
            claimed = -1  # a header cut short: the decompressor finds what it can
        if claimed > size:
            msg = f'zstd frame claims {claimed} bytes, the chunk {size}'
            raise ValueError(msg)
        return bytes(zstandard.ZstdDecompressor().decompressobj().decompress(data))[:size]
    if compression == 'lz4':
        import lz4.frame

        return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size))
    if compression == 'bz2':
        import bz2

        return bz2.BZ2Decompressor().decompress(data, max_length=size)
    msg = f'compression {compression!r} is not supported'
    raise ValueError(msg)


def zero_tail_start(view: memoryview, size: int) -> int:
    """Where the run of zero bytes that ends ``view[:size]`` begins (``size`` when none does).

    A file whose last blocks never reached the disk (power loss) keeps its size but reads as
    zeros from some point on; the readers treat such a file as cut where the zeros begin.
    """
    import numpy as np

    end = size
    block = 4096
    while end > 0:
        start = max(0, end - block)
        with view[start:end] as part:
            values = np.frombuffer(part, np.uint8)
            zeros = not values.any()
            del values  # the slice is released on leaving the block
            if not zeros:
                return start + len(bytes(part).rstrip(b'\x00'))
        end = start
        block = min(block * 4, 1 << 24)
    return 0


class MappedFile:
    """A file opened ``'rb'`` and mapped with ``mmap.ACCESS_READ``."""

    def __init__(self, path: Path) -> None:
        try:
            with path.open('rb') as handle:
                self.size = os.fstat(handle.fileno()).st_size
                if self.size == 0:
                    msg = f'{path}: file is empty'
                    raise SourceError(msg)
                self.map = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
        except OSError as err:
            msg = f'{path}: cannot read: {err.strerror or err}'
            raise SourceError(msg) from err
        self.path = path
        self.view = memoryview(self.map)

    def cut(self, size: int) -> None:
        """Read the file as if it ended at ``size``: nothing after it is seen again."""
        if 0 <= size < self.size:
            whole = self.view
            self.view = whole[:size]
            whole.release()
            self.size = size

    def close(self) -> None:
        """Unmap; a mapping still referenced by yielded messages is freed when they are."""
        with contextlib.suppress(BufferError):
            self.view.release()
            self.map.close()
