"""The tag task's accuracy types: tags against tag ground truth, and the wrong-size hints
(``replaybench.tasks.tags.scoring`` computes them)."""

from dataclasses import dataclass

__all__ = ['TagAccuracy', 'TagSizeHint']


@dataclass(frozen=True, slots=True)
class TagSizeHint:
    """One tag id whose distances one scale factor explains (replaybench.tasks.tags.scoring):
    ``scale`` the median of detected / true distance over its ``detections``, all within
    ``spread_pct`` of it; ``size_m`` the size its poses were solved with, ``suggested_size_m``
    the size that scale implies; ``line`` the sentence the terminal prints."""

    tag_id: int = 0
    detections: int = 0
    scale: float = 1.0
    spread_pct: float = 0.0
    size_m: float = 0.0
    suggested_size_m: float = 0.0
    line: str = ''


@dataclass(frozen=True, slots=True)
class TagAccuracy:
    """Tag accuracy of one (backend, topic) against tag ground truth
    (replaybench.tasks.tags.scoring).

    Counts over the frames with truth; errors over the matched tags (poses: where both have
    one); None where nothing was matched.
    """

    frames: int = 0
    n_truth: int = 0
    n_found: int = 0
    matched: int = 0
    recall: float | None = None
    wrong_ids: int = 0
    phantoms: int = 0
    corner_rmse_px: float | None = None
    trans_err_m: float | None = None
    trans_err_pct: float | None = None
    rot_err_deg: float | None = None
    rot_err_deg_p95: float | None = None
    rot_err_deg_max: float | None = None
    trans_err_m_max: float | None = None
    poses: int = 0
    #: ids whose distances are all off by one factor: a wrong tag size (``TagSizeHint``)
    size_hints: tuple[TagSizeHint, ...] = ()
