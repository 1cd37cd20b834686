from __future__ import annotations

import bz2

import lz4.frame
import numpy as np
import pytest
import zstandard

from replaybench.sources._common import MAX_CHUNK_BYTES, decompress, decompress_partial

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
