"""An MCAP's chunk indexes read at once (``_bulk_index``) give the index that reading them one
record at a time gives: the same messages, order, seq, topics, counts and warnings."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from mcap.writer import CompressionType, Writer

from replaybench.sources import mcap as mcap_module
from replaybench.sources.mcap import McapSource

if TYPE_CHECKING:
    from pathlib import Path


def _write(path: Path, compression: CompressionType) -> Path:
    """Chunks holding one, two or three channels, some with 64 or more messages of a channel
    (read in place) and most with a few (gathered), log times out of file order across
    chunks, and one channel in an encoding that cannot be read."""
    with path.open('wb') as f:
        writer = Writer(f, chunk_size=2048, compression=compression)
        writer.start(profile='', library='tests')
        schema = writer.register_schema(name='std_msgs/String', encoding='ros2msg', data=b'')
        channels = [
            writer.register_channel(topic=f'/t{i}', message_encoding='cdr', schema_id=schema)
            for i in range(3)
        ]
        odd = writer.register_channel(topic='/odd', message_encoding='json', schema_id=0)
        t = 1_000_000_000
        for block in range(60):
            burst = 80 if block % 17 == 0 else 1 + block % 4
            for i in range(burst):
                channel = channels[(block + i) % (1 + block % 3)]
                stamp = t + (block * 7919 + i * 104729) % 5_000_000
                writer.add_message(channel, stamp, bytes([block, i % 256]) * 8, stamp)
            if block % 5 == 0:
                writer.add_message(odd, t, b'{}', t)
        writer.finish()
    return path


def _read(path: Path) -> tuple[object, ...]:
    with McapSource(path) as source:
        messages = [(m.topic, m.log_time_ns, m.seq, bytes(m.data)) for m in source.messages()]
        windowed = [(m.topic, m.seq) for m in source.messages(['/t1'], 1_001_000_000)]
        return (
            messages,
            windowed,
            source.topics(),
            source.skipped_topics(),
            source.warnings,
            source.truncated,
        )


@pytest.mark.parametrize('compression', [CompressionType.NONE, CompressionType.ZSTD])
def test_an_index_read_at_once_is_the_index_read_record_by_record(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: CompressionType
) -> None:
    path = _write(tmp_path / 'mixed.mcap', compression)
    taken: list[bool] = []
    real = mcap_module._bulk_index

    def spy(*args: object) -> object:
        found = real(*args)  # type: ignore[arg-type]
        taken.append(found is not None)
        return found

    monkeypatch.setattr(mcap_module, '_bulk_index', spy)
    at_once = _read(path)
    monkeypatch.setattr(mcap_module, '_bulk_index', lambda *args: None)
    one_by_one = _read(path)
    assert taken == [True]
    assert at_once == one_by_one
    assert len(at_once[0]) > 300  # type: ignore[arg-type]


def test_a_damaged_message_index_is_refused_alike_both_ways(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _write(tmp_path / 'damaged.mcap', CompressionType.NONE)
    data = bytearray(path.read_bytes())
    # a MessageIndex of one entry that claims two: trusted, it would read past its record
    at = data.index(bytes([0x07]) + (2 + 4 + 16).to_bytes(8, 'little'))
    data[at + 11 : at + 15] = (32).to_bytes(4, 'little')
    path.write_bytes(bytes(data))
    at_once = _read(path)
    monkeypatch.setattr(mcap_module, '_bulk_index', lambda *args: None)
    one_by_one = _read(path)
    assert at_once == one_by_one
    assert len(at_once[0]) == 460  # type: ignore[arg-type]  # every message, found by a scan
