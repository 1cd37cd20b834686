"""Hostile ROS 1 bags (uncompressed, bz2 and lz4 chunks): flipped bits, overwritten bytes,
oversized lengths, wrong or missing connection records and images claiming huge sizes."""

from __future__ import annotations

import tracemalloc
from typing import Any

import pytest
from fuzz.fuzzkit import (
    WINDOWS,
    Field,
    bag_image_fields,
    bag_length_fields,
    bag_records_of,
    cleanup,
    fixture_bytes,
    flip_bits,
    fuzz_settings,
    huge_values,
    overwrite,
    put_uint,
    recompressed_bag,
    replay,
    rewrite_bag,
    write_case,
)
from hypothesis import given
from hypothesis import strategies as st

from replaybench.decode.encodings import MAX_SIDE

BAG = 'rgb8.bag'
VARIANTS = ['none', 'bz2', 'lz4']
MEMORY_LIMIT = 200 << 20


def bag_bytes(variant: str) -> bytes:
    return fixture_bytes(BAG) if variant == 'none' else recompressed_bag(BAG, variant)


def positions(data: bytes) -> st.SearchStrategy[int]:
    """Byte positions: mostly in record headers and payload heads, sometimes anywhere."""
    spans = [(r.start, min(r.end, r.data_start + 64)) for r in bag_records_of(data)]
    structural = st.sampled_from(spans).flatmap(lambda s: st.integers(s[0], s[1] - 1))
    return st.one_of(structural, structural, structural, st.integers(0, len(data) - 1))


def mutate(draw: st.DataObject, data: bytes) -> bytes:
    kind = draw.draw(st.sampled_from(['flip', 'overwrite', 'length']), label='kind')
    if kind == 'flip':
        flips = draw.draw(
            st.lists(st.tuples(positions(data), st.integers(0, 7)), min_size=1, max_size=8)
        )
        return flip_bits(data, flips)
    if kind == 'overwrite':
        new = draw.draw(
            st.one_of(
                st.binary(min_size=1, max_size=16),
                st.sampled_from([b'\xff' * 8, b'\x00' * 8, b'op=\x05', b'\x04\x00\x00\x00op=']),
            )
        )
        return overwrite(data, draw.draw(positions(data)), new)
    field: Field = draw.draw(st.sampled_from(bag_length_fields(data)), label='field')
    value = draw.draw(st.sampled_from(huge_values(field.width, len(data), field.value)))
    return put_uint(data, field.pos, field.width, value)


@pytest.mark.parametrize('variant', VARIANTS)
@fuzz_settings(1.5)
@given(draw=st.data(), backends=st.sampled_from([('null',), ('hsv',)]), extra=WINDOWS)
def test_corrupted_bag_replays_or_fails_cleanly(tmp_path, variant, draw, backends, extra):
    case = write_case(tmp_path, {BAG: mutate(draw, bag_bytes(variant))})
    outcome = replay(case / BAG, tmp_path, backends=backends, extra=extra, info=True)
    cleanup(case, outcome.out)


# -- connections (the ROS 1 "schema") -------------------------------------------------------

MSGTYPES = [
    'sensor_msgs/msg/Image',
    'sensor_msgs/msg/CompressedImage',
    'sensor_msgs/msg/CameraInfo',
    'vision_msgs/msg/Detection2DArray',
    'std_msgs/msg/String',
    'garbage/msg/X',
    'a/msg/b/c',
]


@st.composite
def connection_plan(draw) -> dict[int, dict[str, Any]]:
    plan: dict[int, dict[str, Any]] = {}
    for _ in range(draw(st.integers(1, 3))):
        target = draw(st.integers(0, 2))
        what = draw(st.sampled_from(['msgtype', 'msgdef', 'md5sum', 'drop']))
        if what == 'msgtype':
            value = draw(
                st.one_of(
                    st.sampled_from(MSGTYPES),
                    st.from_regex(r'[a-z_]{1,8}/msg/[A-Za-z]{1,8}', fullmatch=True),
                )
            )
        elif what == 'msgdef':
            value = draw(st.one_of(st.just(''), st.text(max_size=40), st.just('uint8[] data\n')))
        elif what == 'md5sum':
            value = draw(st.sampled_from(['*', 'x', '0' * 32, 'z' * 32]))
        else:
            value = True
        plan.setdefault(target, {})[what] = value
    return plan


@fuzz_settings(1.0)
@given(plan=connection_plan(), variant=st.sampled_from(VARIANTS))
def test_bag_with_wrong_or_missing_connections_replays_or_fails_cleanly(tmp_path, plan, variant):
    order = ['/camera/camera_info', '/camera/image_raw', '/ground_truth/detections']

    def connection(topic, msgtype, msgdef, md5sum):
        edit = plan.get(order.index(topic), {})
        if edit.get('drop'):
            return None
        return (
            topic,
            edit.get('msgtype', msgtype),
            edit.get('msgdef', msgdef),
            edit.get('md5sum', md5sum),
        )

    compression, frames = (None, None) if variant == 'none' else (variant, 3)
    data = rewrite_bag(
        BAG,
        tmp_path / 'rewritten.bag',
        connection=connection,
        compression=compression,
        frames=frames,
    )
    case = write_case(tmp_path, {BAG: data})
    outcome = replay(case / BAG, tmp_path, backends=('null', 'hsv'), report=True, info=True)
    cleanup(case, outcome.out)


@pytest.mark.parametrize('conn', [None, b'\x00\x00\x00\x00', b'\x01\x00\x00\x00'])
def test_bag_with_connection_records_removed_fails_cleanly(tmp_path, conn):
    """Connection records (in chunks and in the index) turned into an unknown op."""
    data = fixture_bytes(BAG)
    for record in bag_records_of(data):
        if record.op == 0x07 and (conn is None or data[slice(*record.header['conn'])] == conn):
            data = put_uint(data, record.header['op'][0], 1, 0x7F)
    case = write_case(tmp_path, {BAG: data})
    outcome = replay(case / BAG, tmp_path)
    if conn in (None, b'\x01\x00\x00\x00'):
        assert outcome.code == 2  # the image connection is gone
    cleanup(case, outcome.out)


# -- huge dimensions -----------------------------------------------------------------------

SIDES = [100_000, 65_536, 32_769, 2**31, 2**32 - 1, 0]


@fuzz_settings(0.75)
@given(
    which=st.sets(st.integers(0, 9), min_size=1, max_size=10),
    width=st.sampled_from([*SIDES, 320]),
    height=st.sampled_from([*SIDES, 240]),
    step=st.one_of(st.none(), st.sampled_from([0, 2**31, 2**32 - 1, 300_000])),
)
def test_bag_image_claiming_huge_dimensions_is_rejected_before_allocation(
    tmp_path, which, width, height, step
):
    data = fixture_bytes(BAG)
    for i, fields in enumerate(bag_image_fields(data)):
        if i in which:
            data = put_uint(data, fields['width'].pos, 4, width)
            data = put_uint(data, fields['height'].pos, 4, height)
            if step is not None:
                data = put_uint(data, fields['step'].pos, 4, step)
    case = write_case(tmp_path, {BAG: data})
    tracemalloc.start()
    try:
        outcome = replay(case / BAG, tmp_path, backends=('hsv',))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < MEMORY_LIMIT, f'{peak >> 20} MiB traced'
    huge = not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE)
    if huge and outcome.code == 0:
        bad = [r for r in outcome.rows if int(r['seq']) in which]
        assert bad
        assert all(r['status'] == 'skipped' for r in bad)
    cleanup(case, outcome.out)
