"""A single MCAP file with a regular summary is read lazily (``_lazy_index``): its chunks and
MessageIndex records are read when a reader reaches them, and it gives what reading the whole
index at open gives: the same messages, order, seq, windows, topics, counts and warnings."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest
from mcap.writer import CompressionType, Writer
from sourcebags import read_source, write_mixed_mcap

from replaybench.sources import mcap as mcap_module
from replaybench.sources.mcap import McapSource

if TYPE_CHECKING:
    from pathlib import Path


def _eager(path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[object, ...]:
    with monkeypatch.context() as m:
        m.setattr(mcap_module, '_lazy_index', lambda *args: None)
        return read_source(path)


def _windows(path: Path) -> list[object]:
    """Windows of the replay and single topics, as the replay, the samples and the ground
    truth read them."""
    with McapSource(path) as source:
        times = sorted({m.log_time_ns for m in source.messages()})
        out: list[object] = []
        for lo, hi in [(None, None), (times[5], times[40]), (times[-3], None), (None, times[1])]:
            out.extend(
                [(m.topic, m.log_time_ns, m.seq) for m in source.messages(topics, lo, hi)]
                for topics in (None, ['/t0'], ['/t2', '/odd'], '/t1')
            )
        out.append([m.seq for m in source.messages(['/t1'], times[7], times[7] + 1)])
        return out


@pytest.mark.parametrize(
    'compression', [CompressionType.NONE, CompressionType.ZSTD, CompressionType.LZ4]
)
def test_a_file_read_lazily_gives_what_its_whole_index_read_at_open_gives(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compression: CompressionType
) -> None:
    # chunks of one to three channels whose log times overlap across chunks
    path = write_mixed_mcap(tmp_path / 'mixed.mcap', compression)
    with McapSource(path) as source:
        assert source._lz is not None
    lazy = read_source(path)
    assert lazy == _eager(path, monkeypatch)
    windows = _windows(path)
    with monkeypatch.context() as m:
        m.setattr(mcap_module, '_lazy_index', lambda *args: None)
        assert windows == _windows(path)
    assert len(lazy[0]) > 300  # type: ignore[arg-type]


def test_a_damaged_message_index_found_when_its_chunk_is_reached_reads_that_chunk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _many_chunks(tmp_path / 'damaged.mcap', 60)
    data = bytearray(path.read_bytes())
    # a MessageIndex of one entry that claims two, in a chunk no topic begins or ends in
    one = b'\x07' + (22).to_bytes(8, 'little')
    ats = [i for i in range(len(data)) if data.startswith(one, i)]
    at = ats[len(ats) // 2]
    data[at + 11 : at + 15] = (32).to_bytes(4, 'little')
    path.write_bytes(bytes(data))
    with McapSource(path) as source:
        assert source._lz is not None  # found only when the chunk is read
    scanned: list[int] = []
    real = McapSource._scan_chunk

    def spy(self: McapSource, k: int, *args: object) -> None:
        scanned.append(k)
        real(self, k, *args)  # type: ignore[arg-type]

    with monkeypatch.context() as m:
        m.setattr(McapSource, '_scan_chunk', spy)
        lazy = read_source(path)
    assert len(set(scanned)) == 1  # that chunk, read record by record
    assert lazy == _eager(path, monkeypatch)  # there, every message found by a scan
    assert len(lazy[0]) == 100  # type: ignore[arg-type]


def _many_chunks(path: Path, chunks: int) -> Path:
    with path.open('wb') as f:
        writer = Writer(f, chunk_size=64, compression=CompressionType.NONE)
        writer.start(profile='', library='tests')
        schema = writer.register_schema(name='std_msgs/String', encoding='ros2msg', data=b'')
        a = writer.register_channel(topic='/a', message_encoding='cdr', schema_id=schema)
        b = writer.register_channel(topic='/b', message_encoding='cdr', schema_id=schema)
        for i in range(chunks):
            t = 1_000 + 10 * i
            writer.add_message(a, t, bytes(80), t)
            if i % 3:
                writer.add_message(b, t + 1, bytes(80), t + 1)
        writer.finish()
    return path


def test_opening_a_file_of_many_chunks_reads_the_message_indexes_of_a_few(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = _many_chunks(tmp_path / 'many.mcap', 600)
    read: list[int] = []
    real = McapSource._lazy_rows

    def spy(self: McapSource, table: object, ks: object, *args: object, **kw: object) -> object:
        read.extend(ks.tolist())  # type: ignore[attr-defined]
        return real(self, table, ks, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(McapSource, '_lazy_rows', spy)
    with McapSource(path) as source:
        opened = len(set(read))
        first = next(source.messages())
        assert (first.topic, first.log_time_ns, first.seq) == ('/a', 1_000, 0)
        assert len(set(read)) <= opened + 1
        topics = source.topics()
    assert opened <= 6  # each topic's first and last chunks, not 600
    assert [(t.name, t.count, t.first_ns, t.last_ns) for t in topics] == [
        ('/a', 600, 1_000, 6_990),
        ('/b', 400, 1_011, 6_991),
    ]
    monkeypatch.setattr(McapSource, '_lazy_rows', real)
    assert read_source(path) == _eager(path, monkeypatch)
