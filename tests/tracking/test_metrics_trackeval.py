"""The tracking metrics equal TrackEval's (HOTA, CLEAR, Identity) to 1e-6 on the TUD-Campus and
TUD-Stadtmitte files the motmetrics wheel ships, and on constructed edge cases."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from replaybench.tracking import TrackFrame, box_iou_xywh, read_mot_file, score_tracks

trackeval = pytest.importorskip('trackeval', reason='TrackEval (the dev extra) is not installed')
motmetrics = pytest.importorskip('motmetrics', reason='motmetrics (the dev extra) is not installed')

DATA = Path(motmetrics.__file__).parent / 'data'
SEQUENCES = ['TUD-Campus', 'TUD-Stadtmitte']


def _frames(gt_path: Path, test_path: Path) -> list[TrackFrame]:
    gt, test = read_mot_file(gt_path), read_mot_file(test_path)
    last = max(b.frame for b in (*gt, *test))
    frames = []
    for t in range(1, last + 1):
        g = [b for b in gt if b.frame == t]
        r = [b for b in test if b.frame == t]
        sim = box_iou_xywh(
            np.array([[b.x, b.y, b.w, b.h] for b in g]).reshape(-1, 4),
            np.array([[b.x, b.y, b.w, b.h] for b in r]).reshape(-1, 4),
        )
        frames.append(
            TrackFrame(
                np.array([b.id for b in g], dtype=np.int64),
                np.array([b.id for b in r], dtype=np.int64),
                sim,
            )
        )
    return frames


def _trackeval(frames: list[TrackFrame]) -> dict[str, Any]:
    """TrackEval's own metric classes on the same frames (its ids renumbered 0..n-1)."""
    from trackeval.metrics import CLEAR, HOTA, Identity

    gt_all = sorted({int(i) for f in frames for i in f.gt_ids})
    tr_all = sorted({int(i) for f in frames for i in f.tracker_ids})
    gmap = {v: k for k, v in enumerate(gt_all)}
    tmap = {v: k for k, v in enumerate(tr_all)}
    data = {
        'num_timesteps': len(frames),
        'num_gt_ids': len(gt_all),
        'num_tracker_ids': len(tr_all),
        'num_gt_dets': sum(len(f.gt_ids) for f in frames),
        'num_tracker_dets': sum(len(f.tracker_ids) for f in frames),
        'gt_ids': [np.array([gmap[int(i)] for i in f.gt_ids], dtype=int) for f in frames],
        'tracker_ids': [np.array([tmap[int(i)] for i in f.tracker_ids], dtype=int) for f in frames],
        'similarity_scores': [f.similarity for f in frames],
    }
    config = {'PRINT_CONFIG': False}
    res: dict[str, Any] = {}
    res.update(HOTA(config).eval_sequence(data))
    res.update(CLEAR(config).eval_sequence(data))
    res.update(Identity(config).eval_sequence(data))
    return res


def _check(frames: list[TrackFrame]) -> None:
    mine = score_tracks(frames)
    ref = _trackeval(frames)
    pairs = {
        'hota': np.mean(ref['HOTA']),
        'deta': np.mean(ref['DetA']),
        'assa': np.mean(ref['AssA']),
        'loca': np.mean(ref['LocA']),
        'detre': np.mean(ref['DetRe']),
        'detpr': np.mean(ref['DetPr']),
        'assre': np.mean(ref['AssRe']),
        'asspr': np.mean(ref['AssPr']),
        'mota': ref['MOTA'],
        'motp': ref['MOTP'],
        'id_switches': ref['IDSW'],
        'fragmentations': ref['Frag'],
        'mostly_tracked': ref['MT'],
        'partly_tracked': ref['PT'],
        'mostly_lost': ref['ML'],
        'clr_tp': ref['CLR_TP'],
        'clr_fn': ref['CLR_FN'],
        'clr_fp': ref['CLR_FP'],
        'idf1': ref['IDF1'],
        'idr': ref['IDR'],
        'idp': ref['IDP'],
        'idtp': ref['IDTP'],
        'idfn': ref['IDFN'],
        'idfp': ref['IDFP'],
    }
    for name, expected in pairs.items():
        assert getattr(mine, name) == pytest.approx(float(expected), abs=1e-6), name
    assert mine.hota_per_alpha == pytest.approx(list(ref['HOTA']), abs=1e-6)


@pytest.mark.parametrize('sequence', SEQUENCES)
def test_every_figure_equals_trackevals_on_the_motmetrics_sequences(sequence: str) -> None:
    frames = _frames(DATA / sequence / 'gt.txt', DATA / sequence / 'test.txt')
    assert sum(len(f.gt_ids) for f in frames) > 300  # the real files, not an empty read
    _check(frames)


def test_the_tud_campus_figures_are_what_they_are() -> None:
    """Not a constant to match: the order of magnitude a reader can check against published
    TUD-Campus results of this tracker output (MOTA about 0.5, IDF1 about 0.6)."""
    scores = score_tracks(_frames(DATA / 'TUD-Campus' / 'gt.txt', DATA / 'TUD-Campus' / 'test.txt'))
    assert 0.3 < scores.mota < 0.8
    assert 0.3 < scores.idf1 < 0.9
    assert 0.2 < scores.hota < 0.8
    assert scores.frames == 71


def _random_frames(seed: int, empty_every: int = 0) -> list[TrackFrame]:
    rng = np.random.default_rng(seed)
    frames = []
    for t in range(40):
        n, m = int(rng.integers(0, 6)), int(rng.integers(0, 6))
        if empty_every and t % empty_every == 0:
            n = 0
        gt = rng.choice(8, size=n, replace=False)
        tr = rng.choice(10, size=m, replace=False) + 100
        sim = rng.random((n, m)) * (rng.random((n, m)) > 0.4)
        frames.append(TrackFrame(gt.astype(np.int64), tr.astype(np.int64), sim))
    return frames


@pytest.mark.parametrize('seed', range(6))
def test_random_sequences_with_empty_frames_equal_trackeval(seed: int) -> None:
    _check(_random_frames(seed, empty_every=3 if seed % 2 else 0))


def test_a_sequence_without_tracker_boxes_or_without_truth_equals_trackeval() -> None:
    frames = _random_frames(1)
    no_tracks = [
        TrackFrame(f.gt_ids, np.zeros(0, np.int64), np.zeros((len(f.gt_ids), 0))) for f in frames
    ]
    no_truth = [
        TrackFrame(np.zeros(0, np.int64), f.tracker_ids, np.zeros((0, len(f.tracker_ids))))
        for f in frames
    ]
    for case in (no_tracks, no_truth):
        _check(case)


def test_an_id_twice_in_a_frame_is_refused() -> None:
    with pytest.raises(ValueError, match='twice'):
        score_tracks([TrackFrame(np.array([1, 1]), np.array([2]), np.zeros((2, 1)))])


def test_a_malformed_mot_line_is_one_line_naming_it(tmp_path: Path) -> None:
    from replaybench.errors import UsageError

    bad = tmp_path / 'gt.txt'
    bad.write_text('1,1,10,10,5,5,1,1,1\n2,1,10,x,5,5,1,1,1\n', encoding='utf-8')
    with pytest.raises(UsageError, match=r'gt.txt:2: column 4 is not a number'):
        read_mot_file(bad)
    bad.write_text('1,1,10\n', encoding='utf-8')
    with pytest.raises(UsageError, match=r'gt.txt:1: 3 columns'):
        read_mot_file(bad)
    bad.write_text('0,1,10,10,5,5\n', encoding='utf-8')
    with pytest.raises(UsageError, match='from 1'):
        read_mot_file(bad)
