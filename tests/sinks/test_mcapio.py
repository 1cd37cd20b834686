from __future__ import annotations

import io

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from replaybench.sinks._mcapio import McapWriter

# one step: a new channel (on a new or the last schema, with or without metadata), a metadata
# record, or a message on an existing channel
_KEYS = st.dictionaries(st.text(max_size=8), st.text(max_size=20), max_size=3)
_STEP = st.one_of(
    st.tuples(st.just('channel'), st.booleans(), st.text(max_size=12), _KEYS),
    st.tuples(st.just('metadata'), st.text(max_size=10), _KEYS),
    st.tuples(
        st.just('message'),
        st.integers(0, 50),
        st.integers(0, 2**63 - 1),
        st.binary(max_size=300),
    ),
)


def _write(writer: Writer | McapWriter, steps: list[tuple[object, ...]]) -> None:
    writer.start(profile='ros2', library='test')
    channels: list[int] = []
    schema = 0
    for step in steps:
        if step[0] == 'metadata':
            _, name, data = step
            writer.add_metadata(name, data)  # type: ignore[arg-type]
        elif step[0] == 'channel':
            _, new_schema, topic, metadata = step
            if new_schema or not schema:
                schema = writer.register_schema(
                    name=f'pkg/msg/T{schema}', encoding='ros2msg', data=b'int32 x'
                )
            channels.append(
                writer.register_channel(
                    topic=f'/t{len(channels)}{topic}',
                    message_encoding='cdr',
                    schema_id=schema,
                    metadata=metadata,  # type: ignore[arg-type]
                )
            )
        elif channels:
            _, pick, log_time, data = step
            channel = channels[int(pick) % len(channels)]  # type: ignore[call-overload]
            writer.add_message(
                channel_id=channel,
                log_time=log_time,  # type: ignore[arg-type]
                data=data,  # type: ignore[arg-type]
                publish_time=log_time,  # type: ignore[arg-type]
                sequence=int(pick),  # type: ignore[call-overload]
            )
    writer.finish()


@pytest.mark.parametrize('compression', ['zstd', ''])
@settings(max_examples=60, deadline=None)
@given(steps=st.lists(_STEP, max_size=80), chunk_size=st.sampled_from([64, 500, 1 << 20]))
def test_the_file_is_the_one_the_mcap_library_writes_byte_for_byte(
    compression: str, steps: list[tuple[object, ...]], chunk_size: int
) -> None:
    ours, theirs = io.BytesIO(), io.BytesIO()
    _write(McapWriter(ours, chunk_size=chunk_size, compression=compression), steps)
    kind = CompressionType.ZSTD if compression else CompressionType.NONE
    _write(Writer(theirs, chunk_size=chunk_size, compression=kind), steps)
    assert ours.getvalue() == theirs.getvalue()


def test_the_mcap_reader_reads_every_message_back_through_the_index() -> None:
    stream = io.BytesIO()
    writer = McapWriter(stream, chunk_size=1000)
    writer.start('ros2', 'test')
    schema = writer.register_schema('pkg/msg/T', 'ros2msg', b'int32 x')
    a = writer.register_channel('/a', 'cdr', schema)
    b = writer.register_channel('/b', 'cdr', schema)
    for i in range(200):
        writer.add_message(a if i % 3 else b, 1000 + i, bytes([i % 256]) * 40, 1000 + i, i)
    writer.finish()
    stream.seek(0)
    reader = make_reader(stream)
    got = [(c.topic, m.log_time, m.sequence, m.data) for _, c, m in reader.iter_messages()]
    assert got == [
        ('/b' if i % 3 == 0 else '/a', 1000 + i, i, bytes([i % 256]) * 40) for i in range(200)
    ]
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 200
    assert summary.statistics.chunk_count == len(summary.chunk_indexes) > 1


def test_an_unknown_compression_is_refused() -> None:
    with pytest.raises(ValueError, match='lz5'):
        McapWriter(io.BytesIO(), compression='lz5')
