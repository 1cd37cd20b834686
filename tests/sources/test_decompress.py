from __future__ import annotations

import bz2

import lz4.frame
import numpy as np
import pytest
import zstandard

from replaybench.sources._common import (
    MAX_CHUNK_BYTES,
    decompress,
    decompress_chunk,
    decompress_message,
    decompress_partial,
)

RAW = np.random.default_rng(0).integers(0, 255, 1000, dtype=np.uint8).tobytes() + bytes(100_000)
COMPRESS = {
    'zstd': zstandard.ZstdCompressor().compress,
    'lz4': lz4.frame.compress,
    'bz2': bz2.compress,
}


@pytest.mark.parametrize('codec', sorted(COMPRESS))
def test_a_chunk_of_the_declared_size_decompresses(codec: str) -> None:
    assert decompress(memoryview(COMPRESS[codec](RAW)), codec, len(RAW)) == RAW


@pytest.mark.parametrize('codec', sorted(COMPRESS))
@pytest.mark.parametrize('size', [50, len(RAW) - 1, len(RAW) + 1])
def test_a_chunk_that_holds_more_or_less_than_declared_is_refused(codec: str, size: int) -> None:
    with pytest.raises(ValueError, match=r'claims|holds'):
        decompress(memoryview(COMPRESS[codec](RAW)), codec, size)


@pytest.mark.parametrize('codec', sorted(COMPRESS))
def test_a_declared_size_beyond_the_limit_is_refused_before_decompressing(codec: str) -> None:
    with pytest.raises(ValueError, match='limit'):
        decompress(memoryview(COMPRESS[codec](RAW)), codec, MAX_CHUNK_BYTES + 1)
    with pytest.raises(ValueError, match='limit'):
        decompress_partial(memoryview(COMPRESS[codec](RAW)), codec, MAX_CHUNK_BYTES + 1)


@pytest.mark.parametrize('codec', ['lz4', 'bz2'])
def test_a_cut_chunk_gives_a_prefix_of_at_most_the_declared_size(codec: str) -> None:
    data = COMPRESS[codec](RAW)
    whole = decompress_partial(memoryview(data), codec, len(RAW))
    assert whole == RAW
    capped = decompress_partial(memoryview(data), codec, 500)
    assert capped == RAW[:500]
    cut = decompress_partial(memoryview(data[: len(data) // 2]), codec, len(RAW))
    assert RAW.startswith(cut)


def test_a_cut_zstd_chunk_gives_a_prefix_and_a_lying_frame_is_refused() -> None:
    data = COMPRESS['zstd'](RAW)
    cut = decompress_partial(memoryview(data[: len(data) // 2]), 'zstd', len(RAW))
    assert RAW.startswith(cut)
    assert decompress_partial(memoryview(data[:3]), 'zstd', len(RAW)) == b''
    with pytest.raises(ValueError, match='claims'):
        decompress_partial(memoryview(data), 'zstd', 500)


def test_a_compressed_message_decompresses_with_or_without_a_declared_size() -> None:
    with_size = zstandard.ZstdCompressor().compress(RAW)
    without = zstandard.ZstdCompressor(write_content_size=False).compress(RAW)
    assert zstandard.frame_content_size(without) == -1
    assert decompress_message(with_size) == RAW
    assert decompress_message(memoryview(without)) == RAW


@pytest.mark.parametrize('write_content_size', [True, False])
def test_a_compressed_message_larger_than_the_limit_is_refused(write_content_size: bool) -> None:
    frame = zstandard.ZstdCompressor(write_content_size=write_content_size).compress(RAW)
    with pytest.raises(ValueError, match='limit'):
        decompress_message(frame, limit=len(RAW) - 1)
    assert decompress_message(frame, limit=len(RAW)) == RAW


@pytest.mark.parametrize('data', [b'', b'not zstd at all', bytes(64)])
def test_a_message_that_is_not_a_zstd_frame_is_a_value_error(data: bytes) -> None:
    with pytest.raises(ValueError, match='zstd'):
        decompress_message(data)


@pytest.mark.parametrize('write_content_size', [True, False])
def test_a_cut_zstd_message_is_refused_with_or_without_a_declared_size(
    write_content_size: bool,
) -> None:
    frame = zstandard.ZstdCompressor(write_content_size=write_content_size).compress(RAW)
    with pytest.raises(ValueError, match='zstd'):
        decompress_message(frame[: len(frame) // 2])


@pytest.mark.parametrize('codec', sorted(COMPRESS))
@pytest.mark.parametrize('partial', [False, True])
def test_a_damaged_chunk_is_a_value_error_whatever_the_codec_raises(
    codec: str, partial: bool
) -> None:
    data = bytearray(COMPRESS[codec](RAW))
    data[0:4] = b'\xff' * 4  # the frame's magic number
    view = memoryview(bytes(8) + bytes(data))
    with pytest.raises(ValueError):  # noqa: PT011  the message is the codec's own
        decompress_chunk(view, 8, len(data), codec, len(RAW), partial=partial)
    view.release()  # the chunk's slice was released: nothing holds the buffer


@pytest.mark.parametrize('codec', sorted(COMPRESS))
def test_a_chunk_in_a_larger_buffer_decompresses(codec: str) -> None:
    data = COMPRESS[codec](RAW)
    view = memoryview(b'head' + data + b'tail')
    assert decompress_chunk(view, 4, len(data), codec, len(RAW), partial=False) == RAW
