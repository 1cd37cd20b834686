"""Synchronised frame sets (``replaybench.replay.sync``): exact and approximate pairing of the
topics' header stamps, on hand-made stamps whose sets are known."""

from __future__ import annotations

import random

import pytest

from replaybench.errors import UsageError
from replaybench.replay.sync import Grouping, SyncSpec, group_frames, parse_sync

MS = 1_000_000
PERIOD = 33 * MS  # about 30 Hz
EXACT = SyncSpec('exact')


def _approx(ms: float) -> SyncSpec:
    return SyncSpec('approx', round(ms * MS))


def _train(n: int, start: int = 0, period: int = PERIOD) -> list[int]:
    return [start + k * period for k in range(n)]


def _indices(grouping: Grouping) -> list[tuple[int, ...]]:
    return [s.indices for s in grouping.sets]


def _check_invariants(grouping: Grouping, stamps: list[list[int]], slop_ns: int) -> None:
    """One frame per topic in each set, within the slop, sets in stamp order in every topic,
    no frame in two sets, and the counts adding up."""
    used: list[set[int]] = [set() for _ in stamps]
    previous: tuple[int, ...] | None = None
    for s in grouping.sets:
        assert len(s.indices) == len(stamps)
        assert s.stamps == tuple(stamps[t][i] for t, i in enumerate(s.indices))
        assert s.spread_ns <= slop_ns
        for t, i in enumerate(s.indices):
            assert i not in used[t]
            used[t].add(i)
        if previous is not None:
            assert all(a < b for a, b in zip(previous, s.stamps, strict=True))
        previous = s.stamps
    assert grouping.unpaired == tuple(len(s) - len(grouping.sets) for s in stamps)


def test_exact_pairs_every_frame_of_two_topics_with_the_same_stamps() -> None:
    stamps = [_train(10), _train(10)]
    grouping = group_frames(['/a', '/b'], stamps, EXACT)
    assert _indices(grouping) == [(k, k) for k in range(10)]
    assert grouping.unpaired == (0, 0)
    assert grouping.spread_ns_max == 0


def test_a_frame_missing_in_one_topic_leaves_its_partner_unpaired_and_pairs_the_rest() -> None:
    left = _train(10)
    right = [s for k, s in enumerate(_train(10)) if k != 4]
    for spec in (EXACT, _approx(5)):
        grouping = group_frames(['/a', '/b'], [left, right], spec)
        assert len(grouping.sets) == 9
        assert grouping.unpaired == (1, 0)
        assert 4 not in {s.indices[0] for s in grouping.sets}
        _check_invariants(grouping, [left, right], spec.slop_ns)


def test_a_topic_starting_two_frames_late_leaves_the_first_two_of_the_others_unpaired() -> None:
    early = _train(12)
    late = _train(10, start=2 * PERIOD)
    third = _train(12)
    for spec in (EXACT, _approx(3)):
        grouping = group_frames(['/a', '/late', '/c'], [early, late, third], spec)
        assert grouping.unpaired == (2, 0, 2)
        assert grouping.sets[0].indices == (2, 0, 2)
        assert len(grouping.sets) == 10


def test_jitter_within_the_slop_pairs_every_frame_approximately_but_none_exactly() -> None:
    rng = random.Random(7)
    left = _train(30)
    right = [s + rng.randint(-3 * MS, 3 * MS) for s in left]
    assert len(set(left) & set(right)) == 0
    approx = group_frames(['/a', '/b'], [left, right], _approx(6))
    assert _indices(approx) == [(k, k) for k in range(30)]
    assert approx.spread_ns_max is not None
    assert approx.spread_ns_max <= 3 * MS
    assert group_frames(['/a', '/b'], [left, right], EXACT).sets == ()


def test_a_frame_jittered_beyond_the_slop_pairs_with_nothing() -> None:
    left = _train(10)
    right = list(left)
    right[6] += 10 * MS  # 10 ms off its partner, 23 ms off the next frame: beyond 5 ms
    grouping = group_frames(['/a', '/b'], [left, right], _approx(5))
    assert grouping.unpaired == (1, 1)
    assert (6, 6) not in _indices(grouping)
    assert len(grouping.sets) == 9


def test_the_slop_bounds_the_spread_inclusively() -> None:
    left, right = [0, PERIOD], [5 * MS, PERIOD + 5 * MS + 1]
    grouping = group_frames(['/a', '/b'], [left, right], _approx(5))
    assert _indices(grouping) == [(0, 0)]  # 5 ms is within, 5 ms + 1 ns is not
    assert grouping.unpaired == (1, 1)


def test_approximate_chooses_the_set_of_smallest_spread_not_the_first_that_fits() -> None:
    # /b's frame at 9 ms fits /a's at 0 ms (9 ms) but /a's at 10 ms is nearer (1 ms)
    grouping = group_frames(['/a', '/b'], [[0, 10 * MS], [9 * MS]], _approx(20))
    assert _indices(grouping) == [(1, 0)]
    assert grouping.unpaired == (1, 0)


def test_repeated_stamps_pair_in_order_and_a_surplus_stays_unpaired() -> None:
    left = [0, PERIOD, PERIOD, 2 * PERIOD]
    right = [0, PERIOD, 2 * PERIOD]
    grouping = group_frames(['/a', '/b'], [left, right], EXACT)
    assert _indices(grouping) == [(0, 0), (1, 1), (3, 2)]
    assert grouping.unpaired == (1, 0)
    both = group_frames(['/a', '/b'], [left, [0, PERIOD, PERIOD, 2 * PERIOD]], EXACT)
    assert _indices(both) == [(0, 0), (1, 1), (2, 2), (3, 3)]
    approx = group_frames(['/a', '/b'], [left, right], _approx(1))
    assert len(approx.sets) == 3
    assert approx.unpaired == (1, 0)
    _check_invariants(approx, [left, right], MS)


def test_frames_out_of_stamp_order_in_a_topic_are_paired_by_stamp() -> None:
    left = [2 * PERIOD, 0, PERIOD]
    right = [0, PERIOD, 2 * PERIOD]
    for spec in (EXACT, _approx(1)):
        grouping = group_frames(['/a', '/b'], [left, right], spec)
        assert _indices(grouping) == [(1, 0), (2, 1), (0, 2)]


def test_topics_with_no_stamp_in_common_make_no_set() -> None:
    left = _train(5)
    right = _train(5, start=PERIOD // 2)  # 16.5 ms off every frame of /a
    for spec in (EXACT, _approx(10)):
        grouping = group_frames(['/a', '/b'], [left, right], spec)
        assert grouping.sets == ()
        assert grouping.unpaired == (5, 5)
    assert len(group_frames(['/a', '/b'], [left, right], _approx(17)).sets) > 0


def test_one_topic_makes_each_frame_a_set_of_one() -> None:
    for spec in (EXACT, _approx(5)):
        grouping = group_frames(['/a'], [[0, 0, PERIOD]], spec)
        assert _indices(grouping) == [(0,), (1,), (2,)]
        assert grouping.unpaired == (0,)


def test_random_jittered_rigs_keep_every_invariant_and_give_the_same_sets_twice() -> None:
    rng = random.Random(36)
    for trial in range(40):
        topics = rng.randint(2, 4)
        slop = rng.choice([1, 3, 8, 20]) * MS
        stamps = []
        for _ in range(topics):
            frames = [
                k * PERIOD + rng.randint(-6 * MS, 6 * MS)
                for k in range(rng.randint(0, 4), 25)
                if rng.random() > 0.1  # about one frame in ten missing
            ]
            stamps.append(frames)
        names = [f'/cam{t}' for t in range(topics)]
        grouping = group_frames(names, stamps, SyncSpec('approx', slop))
        _check_invariants(grouping, stamps, slop)
        assert group_frames(names, stamps, SyncSpec('approx', slop)) == grouping, trial


def test_three_topics_with_one_gap_each_keep_the_frames_where_all_three_meet() -> None:
    a = _train(8)
    b = [s for k, s in enumerate(_train(8)) if k != 2]
    c = [s + MS for k, s in enumerate(_train(8)) if k != 5]
    grouping = group_frames(['/a', '/b', '/c'], [a, b, c], _approx(2))
    assert [s.indices[0] for s in grouping.sets] == [0, 1, 3, 4, 6, 7]
    assert grouping.unpaired == (2, 1, 1)


@pytest.mark.parametrize(
    ('text', 'spec'),
    [
        ('exact', SyncSpec('exact')),
        ('approx:5', SyncSpec('approx', 5 * MS)),
        ('approx:0.5', SyncSpec('approx', MS // 2)),
        ('approx:0', SyncSpec('approx', 0)),
    ],
)
def test_the_sync_text_reads_as_its_spec_and_back(text: str, spec: SyncSpec) -> None:
    assert parse_sync(text) == spec
    assert parse_sync(spec.text) == spec


@pytest.mark.parametrize('text', ['approx', 'approx:', 'approx:-1', 'approx:5ms', 'near', '', 5])
def test_a_malformed_sync_text_is_refused_naming_the_option(text: object) -> None:
    with pytest.raises(UsageError, match=r'invalid --sync .*use exact or approx:SLOP_MS'):
        parse_sync(text)
