"""Files cut short: at every chunk boundary and at random points, every complete message replays.

The expected frame count is the number of image messages whose record lies wholly before the
cut, computed from the intact file's indexes with the ``mcap`` library / ``rosbags``.
"""

from __future__ import annotations

import pytest
from fuzz.fuzzkit import (
    LONG,
    bag_chunk_boundaries,
    bag_message_ends,
    cleanup,
    fixture_bytes,
    fuzz_settings,
    mcap_chunk_boundaries,
    mcap_message_ends,
    replay,
    write_case,
)
from hypothesis import example, given
from hypothesis import strategies as st

IMAGE_TOPIC = '/camera/image_raw'


def around(boundaries: tuple[int, ...], size: int) -> list[int]:
    """Each boundary and the bytes either side of it, inside the file."""
    return sorted({c for b in boundaries for c in (b - 1, b, b + 1) if 0 < c < size})


def complete_images(ends: tuple[tuple[str, int], ...], cut: int) -> int:
    return sum(1 for topic, end in ends if topic == IMAGE_TOPIC and end <= cut)


def check_cut(tmp_path, name: str, data: bytes, cut: int, ends) -> None:
    expected = complete_images(ends, cut)
    case = write_case(tmp_path, {name: data[:cut]})
    outcome = replay(case / name, tmp_path)
    if expected:
        assert outcome.code == 0, outcome.stderr
    rows = [r for r in outcome.rows if r['topic'] == IMAGE_TOPIC]
    assert len(rows) == expected, f'cut at {cut}: {len(rows)} frames, {expected} complete'
    assert all(r['status'] == 'ok' for r in rows)
    if outcome.run is not None:
        meta = outcome.run['inputs'][0]
        assert meta['truncated'] or meta['warnings'], 'a cut file replayed without any warning'
        assert [int(r['seq']) for r in rows] == list(range(expected))
    cleanup(case, outcome.out)


MCAP = 'rgb8_raw.mcap'
BAG = 'rgb8.bag'


@pytest.mark.parametrize(
    'cut', around(mcap_chunk_boundaries(MCAP), len(fixture_bytes(MCAP))), ids=str
)
def test_mcap_cut_at_a_chunk_boundary_replays_every_complete_message(tmp_path, cut):
    check_cut(tmp_path, MCAP, fixture_bytes(MCAP), cut, mcap_message_ends(MCAP))


@pytest.mark.parametrize('cut', around(bag_chunk_boundaries(BAG), len(fixture_bytes(BAG))), ids=str)
def test_bag_cut_at_a_chunk_boundary_replays_every_complete_message(tmp_path, cut):
    check_cut(tmp_path, BAG, fixture_bytes(BAG), cut, bag_message_ends(BAG))


def cut_points(ends: tuple[tuple[str, int], ...], size: int) -> st.SearchStrategy[int]:
    """Cuts anywhere, or within a few bytes of a message record's end."""
    near = st.tuples(st.sampled_from([end for _, end in ends]), st.integers(-48, 48)).map(
        lambda p: min(max(1, p[0] + p[1]), size - 1)
    )
    return st.one_of(near, st.integers(1, size - 1))


@fuzz_settings(1.0)
@given(cut=cut_points(mcap_message_ends(MCAP), len(fixture_bytes(MCAP))))
@example(cut=len(fixture_bytes(MCAP)) - 1)
@example(cut=9)
def test_mcap_cut_anywhere_replays_every_complete_message(tmp_path, cut):
    check_cut(tmp_path, MCAP, fixture_bytes(MCAP), cut, mcap_message_ends(MCAP))


@fuzz_settings(1.0)
@given(cut=cut_points(bag_message_ends(BAG), len(fixture_bytes(BAG))))
@example(cut=len(fixture_bytes(BAG)) - 1)
@example(cut=14)
def test_bag_cut_anywhere_replays_every_complete_message(tmp_path, cut):
    check_cut(tmp_path, BAG, fixture_bytes(BAG), cut, bag_message_ends(BAG))


@pytest.mark.parametrize('name', ['jpeg.mcap', 'two_camera.mcap'])
def test_compressed_mcap_cut_at_chunk_boundaries_never_claims_more_frames(tmp_path, name):
    data = fixture_bytes(name)
    cuts = around(mcap_chunk_boundaries(name), len(data))
    if LONG:
        cuts = sorted(set(cuts) | set(range(1, len(data), 997)))
    for cut in cuts:
        case = write_case(tmp_path, {name: data[:cut]})
        outcome = replay(case / name, tmp_path)
        per_topic: dict[str, int] = {}
        for row in outcome.rows:
            per_topic[row['topic']] = per_topic.get(row['topic'], 0) + 1
        assert all(n <= 10 for n in per_topic.values()), per_topic
        cleanup(case, outcome.out)
