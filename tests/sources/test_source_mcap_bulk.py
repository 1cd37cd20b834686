"""An MCAP's chunk indexes read at once (``_bulk_index``, the reader of a file that is not read
lazily) give the index that reading them one record at a time gives: the same messages, order,
seq, topics, counts and warnings. ``test_source_mcap_lazy.py`` holds the lazy reader to the
same."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from mcap.writer import CompressionType
from sourcebags import read_source, write_mixed_mcap

from replaybench.sources import mcap as mcap_module

if TYPE_CHECKING:
    from pathlib import Path


@pytest.mark.parametrize('compression', [CompressionType.NONE, CompressionType.ZSTD])
def test_an_index_read_at_once_is_the_index_read_record_by_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: CompressionType
) -> None:
    path = write_mixed_mcap(tmp_path / 'mixed.mcap', compression)
    taken: list[bool] = []
    real = mcap_module._bulk_index

    def spy(*args: object) -> object:
        found = real(*args)  # type: ignore[arg-type]
        taken.append(found is not None)
        return found

    monkeypatch.setattr(mcap_module, '_lazy_index', lambda *args: None)
    monkeypatch.setattr(mcap_module, '_bulk_index', spy)
    at_once = read_source(path)
    monkeypatch.setattr(mcap_module, '_bulk_index', lambda *args: None)
    one_by_one = read_source(path)
    assert taken == [True]
    assert at_once == one_by_one
    assert len(at_once[0]) > 300  # type: ignore[arg-type]


def test_a_damaged_message_index_is_refused_alike_both_ways(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = write_mixed_mcap(tmp_path / 'damaged.mcap', CompressionType.NONE)
    data = bytearray(path.read_bytes())
    # a MessageIndex of one entry that claims two: trusted, it would read past its record
    at = data.index(bytes([0x07]) + (2 + 4 + 16).to_bytes(8, 'little'))
    data[at + 11 : at + 15] = (32).to_bytes(4, 'little')
    path.write_bytes(bytes(data))
    monkeypatch.setattr(mcap_module, '_lazy_index', lambda *args: None)
    at_once = read_source(path)
    monkeypatch.setattr(mcap_module, '_bulk_index', lambda *args: None)
    one_by_one = read_source(path)
    assert at_once == one_by_one
    assert len(at_once[0]) == 460  # type: ignore[arg-type]  # every message, found by a scan
