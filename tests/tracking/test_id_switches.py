"""The CLEAR matching behind ``id_switches`` (``clear_matching``): its switch events counted by
hand on a small sequence and as many as TrackEval's IDSW on it and on the motmetrics
sequences; and a tracked row's id-switch timeline made of it (``timeline_of``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from replaybench.results.model import IdSwitchEvent, TrackSpan
from replaybench.tasks.tracks.recording import score_sequence, timeline_of
from replaybench.tracking import (
    IdSwitch,
    TrackFrame,
    box_iou_xywh,
    clear_matching,
    read_mot_file,
    score_and_match,
    score_tracks,
)
from replaybench.types import Detection


def _frame(pairs: dict[tuple[int, int], float], gt: list[int], tr: list[int]) -> TrackFrame:
    sim = np.zeros((len(gt), len(tr)))
    for (g, t), value in pairs.items():
        sim[gt.index(g), tr.index(t)] = value
    return TrackFrame(np.array(gt, np.int64), np.array(tr, np.int64), sim)


def _trackeval_clear(frames: list[TrackFrame]) -> dict[str, Any]:
    """TrackEval's CLEAR on the frames (its ids renumbered 0..n-1)."""
    trackeval = pytest.importorskip('trackeval', reason='TrackEval (the dev extra) is missing')
    gt_all = sorted({int(i) for f in frames for i in f.gt_ids})
    tr_all = sorted({int(i) for f in frames for i in f.tracker_ids})
    data = {
        'num_timesteps': len(frames),
        'num_gt_ids': len(gt_all),
        'num_tracker_ids': len(tr_all),
        'num_gt_dets': sum(len(f.gt_ids) for f in frames),
        'num_tracker_dets': sum(len(f.tracker_ids) for f in frames),
        'gt_ids': [np.array([gt_all.index(int(i)) for i in f.gt_ids], int) for f in frames],
        'tracker_ids': [
            np.array([tr_all.index(int(i)) for i in f.tracker_ids], int) for f in frames
        ],
        'similarity_scores': [f.similarity for f in frames],
    }
    found: dict[str, Any] = trackeval.metrics.CLEAR({'PRINT_CONFIG': False}).eval_sequence(data)
    return found


def _hand_built() -> list[TrackFrame]:
    """Two objects (1, 2) and tracks 10, 20, 30, 40; the switches counted by hand:

    0: 1-10, 2-20.
    1: 1-20, 2-10: two switches (1: 10 -> 20, 2: 20 -> 10).
    2: 1 missed (its only box below IoU 0.5), 2-10.
    3: 1-30: a switch after the gap (20 -> 30); 2-10.
    4: 1-30 kept although 40 overlaps it more (CLEAR keeps last frame's pair); 2-10.
    5: no tracks at all.
    6: 1-20: a switch (30 -> 20); 2 is not in the truth, track 10 a false positive.
    """
    return [
        _frame({(1, 10): 0.9, (2, 20): 0.8}, [1, 2], [10, 20]),
        _frame({(1, 20): 0.9, (2, 10): 0.7}, [1, 2], [10, 20]),
        _frame({(1, 20): 0.3, (2, 10): 0.9}, [1, 2], [10, 20]),
        _frame({(1, 30): 0.6, (2, 10): 0.9}, [1, 2], [10, 30]),
        _frame({(1, 30): 0.6, (1, 40): 0.95, (2, 10): 0.9}, [1, 2], [10, 30, 40]),
        _frame({}, [1, 2], []),
        _frame({(1, 20): 0.8}, [1], [10, 20]),
    ]


def test_the_switches_of_a_hand_built_sequence_are_those_counted_by_hand() -> None:
    matching = clear_matching(_hand_built())
    assert matching.switches == (
        IdSwitch(frame=1, gt_id=1, from_id=10, to_id=20),
        IdSwitch(frame=1, gt_id=2, from_id=20, to_id=10),
        IdSwitch(frame=3, gt_id=1, from_id=20, to_id=30),
        IdSwitch(frame=6, gt_id=1, from_id=30, to_id=20),
    )
    assert matching.pairs == (
        ((1, 10), (2, 20)),
        ((1, 20), (2, 10)),
        ((2, 10),),
        ((1, 30), (2, 10)),
        ((1, 30), (2, 10)),
        (),
        ((1, 20),),
    )
    assert score_tracks(_hand_built()).id_switches == 4


def test_the_hand_built_switches_are_trackevals_idsw() -> None:
    frames = _hand_built()
    ref = _trackeval_clear(frames)
    assert ref['IDSW'] == len(clear_matching(frames).switches) == 4
    assert ref['CLR_TP'] == sum(len(p) for p in clear_matching(frames).pairs)


def test_frames_without_any_track_or_truth_have_no_pairs_and_no_switches() -> None:
    empty = [_frame({}, [1, 2], []), _frame({}, [1], [])]
    assert clear_matching(empty).pairs == ((), ())
    assert clear_matching(empty).switches == ()
    no_truth = [_frame({}, [], [5]), _frame({}, [], [])]
    assert clear_matching(no_truth).pairs == ((), ())


@pytest.mark.parametrize('sequence', ['TUD-Campus', 'TUD-Stadtmitte'])
def test_the_switch_events_are_as_many_as_trackevals_idsw_on_the_motmetrics_files(
    sequence: str,
) -> None:
    motmetrics = pytest.importorskip('motmetrics', reason='motmetrics (the dev extra) is missing')
    folder = Path(motmetrics.__file__).parent / 'data' / sequence
    gt, test = read_mot_file(folder / 'gt.txt'), read_mot_file(folder / 'test.txt')
    frames = []
    for t in range(1, max(b.frame for b in (*gt, *test)) + 1):
        g = [b for b in gt if b.frame == t]
        r = [b for b in test if b.frame == t]
        frames.append(
            TrackFrame(
                np.array([b.id for b in g], np.int64),
                np.array([b.id for b in r], np.int64),
                box_iou_xywh(
                    np.array([[b.x, b.y, b.w, b.h] for b in g]).reshape(-1, 4),
                    np.array([[b.x, b.y, b.w, b.h] for b in r]).reshape(-1, 4),
                ),
            )
        )
    ref = _trackeval_clear(frames)
    matching = clear_matching(frames)
    assert ref['IDSW'] > 0
    assert len(matching.switches) == ref['IDSW'] == score_tracks(frames).id_switches
    assert sum(len(p) for p in matching.pairs) == ref['CLR_TP']
    # scored in one pass with its matching: every figure as score_tracks gives it
    assert score_and_match(frames) == (score_tracks(frames), matching)
    # each switch names the id its object had at its previous match, and the one it has now
    last: dict[int, int] = {}
    switches = iter(matching.switches)
    for number, pairs in enumerate(matching.pairs):
        for obj, track in pairs:
            if obj in last and last[obj] != track:
                assert next(switches) == IdSwitch(number, obj, last[obj], track)
            last[obj] = track
    assert next(switches, None) is None


def _box(x: float, ident: str) -> Detection:
    return Detection(0, 'thing', 1.0, x, 0.0, x + 10.0, 10.0, ident)


def test_a_rows_timeline_has_each_objects_matched_missed_and_absent_frames_and_its_switches() -> (
    None
):
    a, b = _box(0, 'a'), _box(50, 'b')
    far = _box(200, '')
    frames = [
        ((a, b), (_box(0, '7'), _box(50, '8'))),
        ((a, b), (_box(0, '7'), _box(50, '8'))),
        ((a,), (_box(0, '8'),)),  # b not in the truth; a now on track 8: a switch
        ((a, b), (far._replace(id='7'),)),  # both missed
        ((a, b), (_box(0, '8'), _box(50, '9'))),  # b on 9: a switch across its gap
    ]
    timeline = timeline_of(frames)
    assert timeline.frames == 5
    assert [lane.object_id for lane in timeline.lanes] == ['a', 'b']
    assert timeline.lanes[0].spans == (
        TrackSpan(0, 1, '7'),
        TrackSpan(2, 2, '8'),
        TrackSpan(3, 3, None),
        TrackSpan(4, 4, '8'),
    )
    assert timeline.lanes[1].spans == (
        TrackSpan(0, 1, '8'),
        TrackSpan(3, 3, None),
        TrackSpan(4, 4, '9'),
    )
    assert timeline.switches == (
        IdSwitchEvent(2, 'a', '7', '8'),
        IdSwitchEvent(4, 'b', '8', '9'),
    )
    assert score_sequence(frames).id_switches == 2


def test_the_lanes_are_in_id_order_numbers_by_value_first() -> None:
    boxes = [_box(20.0 * i, ident) for i, ident in enumerate(['10', 'x', '9', '2'])]
    timeline = timeline_of([(tuple(boxes), ())])
    assert [lane.object_id for lane in timeline.lanes] == ['2', '9', '10', 'x']
    assert all(lane.spans == (TrackSpan(0, 0, None),) for lane in timeline.lanes)
