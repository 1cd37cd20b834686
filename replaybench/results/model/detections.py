"""The detection task's accuracy types: COCO-style accuracy against ground-truth boxes, and
how two backends' boxes agree (``replaybench.results.accuracy``, ``results.agreement``)."""

from collections.abc import Mapping
from dataclasses import dataclass, field

from replaybench.results.model.common import empty_mapping

__all__ = ['Accuracy', 'AgreementRow']


@dataclass(frozen=True, slots=True)
class Accuracy:
    """Accuracy of one (backend, topic) against ground truth (COCO-style, by class label).

    ``ap50`` / ``ap50_95`` map each label to its AP; -1 for a label without ground truth.
    """

    frames: int | None = None
    precision50: float | None = None
    recall50: float | None = None
    map50: float | None = None
    map50_95: float | None = None
    ap50: Mapping[str, float] = field(default_factory=empty_mapping)
    ap50_95: Mapping[str, float] = field(default_factory=empty_mapping)
    n_gt: int | None = None
    n_det: int | None = None


@dataclass(frozen=True, slots=True)
class AgreementRow:
    """How two backends agree on one topic (``replaybench.results.agreement``)."""

    backend_a: str = ''
    backend_b: str = ''
    topic: str = ''
    frames: int = 0
    n_a: int = 0
    n_b: int = 0
    matched: int = 0
    matched_frac_a: float | None = None
    matched_frac_b: float | None = None
    mean_iou: float | None = None
    mean_abs_score_diff: float | None = None
    #: (input, seq) of the frames with the most unmatched detections, worst first
    disagreeing_frames: tuple[tuple[int, int], ...] = ()
