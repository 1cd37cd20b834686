"""A detection model's pipeline on one torch device (``DnnPipeline``) for ``cuda`` /
``tensorrt``: upload and preprocessing (``_upload.DeviceInput``), then decode, class-aware greedy
NMS (torch ops, no torchvision) and the mapping to source pixels on the device; only the kept
boxes come back to the host, as Detections (``to_detections``)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from replaybench.backends.gpu import _torch_ops as ops
from replaybench.backends.gpu._upload import DeviceInput
from replaybench.detector.decoders import NonfiniteTally
from replaybench.types import Detection

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

    from replaybench.detector.preprocess import Transform
    from replaybench.detector.spec import ModelSpec
    from replaybench.types import LabelMask

__all__ = ['DnnPipeline', 'to_detections']

Tensor = Any  # torch.Tensor


def to_detections(rows: npt.NDArray[Any], class_names: Sequence[str]) -> tuple[Detection, ...]:
    """Downloaded ``[K, 6]`` rows (source-pixel box, score, class) -> Detections.

    As ``decoders.postprocess``: boxes left empty by clipping are dropped; labels from the
    class names (the class index as text beyond them); sorted by (-score, class, x0, y0).
    """
    n_names = len(class_names)
    found: list[Detection] = []
    for x0, y0, x1, y1, score, cls in rows.tolist():
        if x1 <= x0 or y1 <= y0:
            continue
        cid = int(cls)
        label = class_names[cid] if 0 <= cid < n_names else str(cid)
        found.append(Detection(cid, label, score, x0, y0, x1, y1))
    found.sort(key=lambda d: (-d.score, d.class_index, d.x0, d.y0))
    return tuple(found)


class DnnPipeline(DeviceInput):
    """Upload, preprocessing (``DeviceInput``) and postprocessing of one detection model on
    one torch device."""

    def __init__(
        self,
        torch: Any,
        spec: ModelSpec,
        device: Any,
        half: bool,
        conf: float,
        iou: float,
        max_det: int,
    ) -> None:
        super().__init__(torch, spec.preprocess, device, half)
        self.spec = spec
        self.conf = conf
        self.iou = iou
        self.max_det = max_det
        self._grid = None
        if spec.family == 'yolox':
            self._grid = ops.yolox_grid(torch, spec.preprocess.size, device)
        #: Candidates left out for NaN or inf model outputs.
        self.nonfinite = NonfiniteTally()

    def postprocess(self, outputs: Mapping[str, Tensor], transform: Transform) -> list[Tensor]:
        """What to download: ``[rows K x 6]`` and the count of candidates left out for NaN or
        inf values (0-d) for YOLO heads; the raw outputs for ``nms`` ones."""
        torch = self.torch
        spec = self.spec
        if spec.family == 'nms':
            return [outputs[name] for name in spec.output_names]
        out = outputs[spec.output_names[0]]
        boxes, scores, classes, nonfinite = ops.decode(
            torch, spec.family, out, self.conf, self._grid
        )
        keep = ops.batched_nms(torch, boxes, scores, classes, self.iou, self.max_det)
        src = ops.boxes_to_source(torch, boxes[keep], transform)
        rows = torch.cat((src, scores[keep, None], classes[keep, None].to(torch.float32)), dim=1)
        return [rows, nonfinite]

    def detections(
        self, arrays: Sequence[npt.NDArray[Any]], transform: Transform
    ) -> tuple[Detection, ...]:
        """Detections from the downloaded arrays (``nms`` models: the numpy decoder)."""
        spec = self.spec
        if spec.family == 'nms':
            from replaybench.detector.decoders import postprocess

            outputs = dict(zip(spec.output_names, arrays, strict=True))
            return postprocess(
                outputs, spec, transform, self.conf, self.iou, self.max_det, self.nonfinite
            )
        self.nonfinite.add(int(arrays[1]))
        return to_detections(arrays[0], spec.class_names)

    def answer(
        self, arrays: Sequence[npt.NDArray[Any]], transform: Transform
    ) -> tuple[tuple[Detection, ...], LabelMask | None]:
        """The frame's detections and label mask (``_seg.SegPipeline``: a mask)."""
        return self.detections(arrays, transform), None
