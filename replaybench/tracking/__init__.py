"""Multi-object tracking: the sequence metrics (HOTA, CLEAR, identity) and the MOTChallenge
file format. The library under the tracking task; it imports nothing of the engine."""

from __future__ import annotations

from replaybench.tracking.metrics import (
    HOTA_ALPHAS,
    ClearMatching,
    IdSwitch,
    TrackFrame,
    TrackScores,
    box_iou_xywh,
    clear_matching,
    score_and_match,
    score_tracks,
)
from replaybench.tracking.motfile import MotBox, read_mot_file

__all__ = [
    'HOTA_ALPHAS',
    'ClearMatching',
    'IdSwitch',
    'MotBox',
    'TrackFrame',
    'TrackScores',
    'box_iou_xywh',
    'clear_matching',
    'read_mot_file',
    'score_and_match',
    'score_tracks',
]
