"""Hostile MCAP files: flipped bits, overwritten bytes, oversized lengths, bad or missing schemas
and images claiming huge sizes. Every mutant replays through the real CLI without a traceback,
in bounded time and memory, and never leaves a failed run that claims to be complete."""

from __future__ import annotations

import tracemalloc
from typing import Any

import pytest
from fuzz.fuzzkit import (
    OP_CHANNEL,
    OP_SCHEMA,
    WINDOWS,
    Field,
    cleanup,
    drop_records,
    fixture_bytes,
    flip_bits,
    fuzz_settings,
    huge_values,
    mcap_image_fields,
    mcap_length_fields,
    mcap_records,
    overwrite,
    patch_sof,
    put_uint,
    replay,
    rewrite_mcap,
    structural_spans,
    write_case,
)
from hypothesis import given
from hypothesis import strategies as st

from replaybench.decode.encodings import MAX_SIDE

MCAPS = ['rgb8_raw.mcap', 'jpeg.mcap', 'two_camera.mcap']
BACKENDS = st.sampled_from([('null',), ('hsv',), ('null', 'hsv')])
#: Peak traced allocation allowed while replaying an image that claims huge dimensions.
MEMORY_LIMIT = 200 << 20


def positions(name: str) -> st.SearchStrategy[int]:
    """Byte positions: mostly in record headers and payload heads, sometimes anywhere."""
    spans = structural_spans(mcap_records(name))
    structural = st.sampled_from(spans).flatmap(lambda s: st.integers(s[0], s[1] - 1))
    return st.one_of(
        structural, structural, structural, st.integers(0, len(fixture_bytes(name)) - 1)
    )


def mutate(draw: st.DataObject, name: str) -> bytes:
    data = fixture_bytes(name)
    kind = draw.draw(st.sampled_from(['flip', 'overwrite', 'length']), label='kind')
    if kind == 'flip':
        flips = draw.draw(
            st.lists(st.tuples(positions(name), st.integers(0, 7)), min_size=1, max_size=8)
        )
        return flip_bits(data, flips)
    if kind == 'overwrite':
        new = draw.draw(
            st.one_of(
                st.binary(min_size=1, max_size=16),
                st.sampled_from([b'\xff' * 8, b'\x00' * 8, b'\x7f\xff\xff\xff']),
            )
        )
        return overwrite(data, draw.draw(positions(name)), new)
    field: Field = draw.draw(st.sampled_from(mcap_length_fields(name)), label='field')
    value = draw.draw(st.sampled_from(huge_values(field.width, len(data), field.value)))
    return put_uint(data, field.pos, field.width, value)


@pytest.mark.parametrize('name', MCAPS)
@fuzz_settings(1.5)
@given(draw=st.data(), backends=BACKENDS, extra=WINDOWS)
def test_corrupted_mcap_replays_or_fails_cleanly(tmp_path, name, draw, backends, extra):
    case = write_case(tmp_path, {name: mutate(draw, name)})
    outcome = replay(case / name, tmp_path, backends=backends, extra=extra, info=True)
    cleanup(case, outcome.out)


# -- schemas and channels ------------------------------------------------------------------

SCHEMA_NAMES = [
    '',
    'garbage',
    'sensor_msgs/msg/Image',
    'sensor_msgs/msg/CompressedImage',
    'sensor_msgs/msg/CameraInfo',
    'sensor_msgs/Image',
    'vision_msgs/msg/Detection2DArray',
    'foxglove.RawImage',
    'foxglove.CompressedImage',
    'foxglove.CameraCalibration',
]
SCHEMA_ENCODINGS = ['', 'ros2msg', 'ros1msg', 'ros2idl', 'protobuf', 'jsonschema', 'flatbuffer']
MESSAGE_ENCODINGS = ['', 'cdr', 'ros1', 'protobuf', 'json', 'CDR']
TEXT = st.text(max_size=24)
TOPICS = [
    '',
    '/',
    '//a//b/',
    '/camera/image_raw',
    '/ground_truth/detections',
    '<b>&"x\'</b>',
    '/cam/../..',
    '/\u00e9\u00e8/\u2603',
    '/' + 'x' * 300,
]


@st.composite
def schema_plan(draw) -> dict[str, Any]:
    """Which schema / channel fields to rewrite, and to what."""
    ids = st.integers(1, 5)
    plan: dict[str, Any] = {'schema': {}, 'channel': {}}
    for _ in range(draw(st.integers(1, 3))):
        target = draw(ids)
        what = draw(
            st.sampled_from(['name', 'encoding', 'data', 'schema_id', 'msg_encoding', 'topic'])
        )
        if what == 'name':
            value = draw(st.one_of(st.sampled_from(SCHEMA_NAMES), TEXT))
            plan['schema'].setdefault(target, {})['name'] = value
        elif what == 'encoding':
            value = draw(st.one_of(st.sampled_from(SCHEMA_ENCODINGS), TEXT))
            plan['schema'].setdefault(target, {})['encoding'] = value
        elif what == 'data':
            value = draw(st.one_of(st.just(b''), st.binary(max_size=64)))
            plan['schema'].setdefault(target, {})['data'] = value
        elif what == 'schema_id':
            value = draw(st.sampled_from([0, 1, 2, 3, 99, 65535]))
            plan['channel'].setdefault(target, {})['schema_id'] = value
        elif what == 'msg_encoding':
            value = draw(st.one_of(st.sampled_from(MESSAGE_ENCODINGS), TEXT))
            plan['channel'].setdefault(target, {})['encoding'] = value
        else:
            value = draw(st.one_of(st.sampled_from(TOPICS), TEXT))
            plan['channel'].setdefault(target, {})['topic'] = value
    return plan


def apply_plan(name: str, plan: dict[str, Any]) -> bytes:
    def schema(sid, sname, encoding, data):
        edit = plan['schema'].get(sid, {})
        return edit.get('name', sname), edit.get('encoding', encoding), edit.get('data', data)

    def channel(cid, topic, encoding, schema_id):
        edit = plan['channel'].get(cid, {})
        return (
            edit.get('topic', topic),
            edit.get('encoding', encoding),
            edit.get('schema_id', schema_id),
        )

    compression = 'none' if name == 'rgb8_raw.mcap' else 'zstd'
    return rewrite_mcap(
        fixture_bytes(name), schema=schema, channel=channel, compression=compression
    )


@pytest.mark.parametrize('name', ['rgb8_raw.mcap', 'two_camera.mcap'])
@fuzz_settings(1.0)
@given(plan=schema_plan())
def test_mcap_with_wrong_schemas_replays_or_fails_cleanly(tmp_path, name, plan):
    case = write_case(tmp_path, {name: apply_plan(name, plan)})
    outcome = replay(case / name, tmp_path, backends=('null', 'hsv'), report=True, info=True)
    cleanup(case, outcome.out)


@pytest.mark.parametrize('name', MCAPS)
@pytest.mark.parametrize(
    ('op', 'ids'),
    [(OP_SCHEMA, None), (OP_SCHEMA, {2}), (OP_SCHEMA, {1, 3}), (OP_CHANNEL, None),
     (OP_CHANNEL, {2}), (OP_CHANNEL, {1, 3})],
    ids=['all-schemas', 'image-schema', 'other-schemas', 'all-channels', 'image-channel',
         'other-channels'],
)  # fmt: skip
def test_mcap_with_dropped_schema_or_channel_records_fails_cleanly(tmp_path, name, op, ids):
    case = write_case(tmp_path, {name: drop_records(name, op, ids)})
    outcome = replay(case / name, tmp_path, backends=('null',))
    if op == OP_SCHEMA and ids in (None, {2}) and name == 'rgb8_raw.mcap':
        # Indexed and in-chunk copies of the schema are gone: no image topic is left.
        assert outcome.code == 2
    cleanup(case, outcome.out)


# -- huge dimensions -----------------------------------------------------------------------

SIDES = [100_000, 65_536, 32_769, 32_768, 16_385, 2**31, 2**32 - 1, 0, 1]


@fuzz_settings(1.0)
@given(
    which=st.integers(0, 9),
    width=st.sampled_from([*SIDES, 320]),
    height=st.sampled_from([*SIDES, 240]),
    step=st.one_of(st.none(), st.sampled_from([0, 960, 300_000, 2**31, 2**32 - 1])),
    data_len=st.one_of(st.none(), st.sampled_from([0, 2**31, 2**32 - 1, 300_000])),
)
def test_raw_image_claiming_huge_dimensions_is_rejected_before_allocation(
    tmp_path, which, width, height, step, data_len
):
    name = 'rgb8_raw.mcap'
    data = fixture_bytes(name)
    fields = mcap_image_fields(name)[which]
    data = put_uint(data, fields['width'].pos, 4, width)
    data = put_uint(data, fields['height'].pos, 4, height)
    if step is not None:
        data = put_uint(data, fields['step'].pos, 4, step)
    if data_len is not None:
        data = put_uint(data, fields['data_len'].pos, 4, data_len)
    case = write_case(tmp_path, {name: data})
    tracemalloc.start()
    try:
        outcome = replay(case / name, tmp_path, backends=('hsv',))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_LIMIT, f'{peak >> 20} MiB traced'
    if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE) and outcome.code == 0:
        rows = [r for r in outcome.rows if r['seq'] == str(which)]
        assert rows
        assert all(r['status'] == 'skipped' for r in rows)
    cleanup(case, outcome.out)


@fuzz_settings(1.0)
@given(
    which=st.sets(st.integers(0, 9), min_size=1, max_size=10),
    width=st.sampled_from([65_535, 40_000, 32_768, 16_000, 8_192, 4_097, 320, 0]),
    height=st.sampled_from([65_535, 32_768, 16_000, 8_192, 4_097, 240, 1, 0]),
)
def test_jpeg_claiming_huge_dimensions_is_rejected_before_allocation(
    tmp_path, which, width, height
):
    name = 'jpeg.mcap'
    seen: dict[str, int] = {}

    def message(topic: str, payload: bytes) -> bytes:
        if not topic.endswith('/compressed'):
            return payload
        n = seen[topic] = seen.get(topic, -1) + 1
        if n not in which:
            return payload
        start = payload.index(b'\xff\xd8\xff')
        return payload[:start] + patch_sof(payload[start:], width, height)

    data = rewrite_mcap(fixture_bytes(name), message=message, compression='zstd')
    case = write_case(tmp_path, {name: data})
    tracemalloc.start()
    try:
        outcome = replay(case / name, tmp_path, backends=('hsv',))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_LIMIT, f'{peak >> 20} MiB traced'
    cleanup(case, outcome.out)
