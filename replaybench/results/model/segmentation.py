"""The segmentation task's accuracy types: a backend's masks against ground-truth masks, and
two backends' masks against each other (``replaybench.tasks.segmentation.scoring``)."""

from collections.abc import Mapping
from dataclasses import dataclass, field

from replaybench.results.model.common import empty_mapping

__all__ = ['SegmentationAgreementRow', 'SegmentationSummary']


@dataclass(frozen=True, slots=True)
class SegmentationSummary:
    """A segmentation backend's accuracy on one topic (``replaybench.tasks.segmentation.scoring``):
    frames scored against a ground-truth mask, mIoU, pixel accuracy, IoU by class name (classes
    in the truth or the prediction), and the backend's class names by id."""

    frames: int = 0
    miou: float | None = None
    pixel_accuracy: float | None = None
    iou: Mapping[str, float] = field(default_factory=empty_mapping)
    class_names: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class SegmentationAgreementRow:
    """Two segmentation backends on one topic: over the frames both labelled, the mIoU and
    pixel agreement of ``backend_b``'s masks taking ``backend_a``'s as ground truth."""

    backend_a: str = ''
    backend_b: str = ''
    topic: str = ''
    frames: int = 0
    miou: float | None = None
    pixel_agreement: float | None = None
