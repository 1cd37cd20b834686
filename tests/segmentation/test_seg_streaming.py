"""Streaming mIoU: each frame's truth mask against the mask in use at its release, on the
virtual clock. A test backend returns each frame's own truth mask after a set delay; the
expected figures are counted here pixel by pixel from the fixture's masks."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pytest

from replaybench.backends.base import Availability
from replaybench.fixtures.masks import MASK_CLASS_NAMES, semantic_labels
from replaybench.fixtures.scene import Scene
from replaybench.fixtures.writer import stamp_ns, write_mcap
from replaybench.replay import Rate, VirtualClock
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.types import BackendResult, LabelMask, StageTimes

if TYPE_CHECKING:
    from collections.abc import Mapping
    from pathlib import Path

    from replaybench.types import Frame

FRAMES = 8
SIZE = (160, 120)
IGNORE = 255


class DelayedMasks:
    """Each frame's truth mask, after ``delay_s`` on the virtual clock (task segmentation)."""

    name: ClassVar[str] = 'masks'
    description: ClassVar[str] = 'truth masks after a delay'
    task: ClassVar[str] = 'segmentation'

    def __init__(self, clock: VirtualClock, delay_s: float) -> None:
        self.clock = clock
        self.delay_s = delay_s
        scene = Scene(SIZE)
        self.masks = {stamp_ns(i): semantic_labels(scene, i) for i in range(FRAMES)}

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        self.clock.advance(self.delay_s)
        labels = self.masks[frame.stamp_ns].copy()
        return BackendResult((), StageTimes(), mask=LabelMask(labels, tuple(MASK_CLASS_NAMES)))

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


def _expected(shown: Mapping[int, int | None]) -> tuple[float, float]:
    """mIoU and pixel accuracy of truth frame i against frame shown[i]'s truth (no answer:
    every pixel unlabelled), pooled over the frames, counted pixel by pixel."""
    scene = Scene(SIZE)
    truth = {i: semantic_labels(scene, i) for i in range(FRAMES)}
    inter: dict[int, int] = {}
    union: dict[int, int] = {}
    right = total = 0
    for i, j in shown.items():
        gt = truth[i]
        pred = np.full(gt.shape, IGNORE, np.uint8) if j is None else truth[j]
        keep = gt != IGNORE
        gt, pred = gt[keep], pred[keep]
        right += int(np.sum(gt == pred))
        total += gt.size
        for c in set(np.unique(gt).tolist()) | set(np.unique(pred).tolist()):
            if c == IGNORE:
                continue
            inter[c] = inter.get(c, 0) + int(np.sum((gt == c) & (pred == c)))
            union[c] = union.get(c, 0) + int(np.sum((gt == c) | (pred == c)))
    ious = [inter[c] / union[c] for c in union if union[c]]
    return float(np.mean(ious)), right / total


@pytest.mark.parametrize(('delay_s', 'behind'), [(0.0, 0), (0.020, 1)])
def test_the_streaming_miou_is_the_mask_of_the_frame_in_use_as_counted(
    tmp_path: Path, delay_s: float, behind: int
) -> None:
    bag = write_mcap(tmp_path / 'seg.mcap', FRAMES, SIZE, masks=True)
    clock = VirtualClock()
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['masks'],
            out_dir=tmp_path / 'run',
            rate=Rate('fixed', hz=30.0),
            warmup=0,
            report=False,
            hash_inputs=False,
        ),
        clock=clock,
        backend_factory=lambda _name, _options: DelayedMasks(clock, delay_s),
    )
    [row] = outcome.summaries
    assert row.task_metrics is not None
    miou, accuracy = _expected({i: i - behind if i >= behind else None for i in range(FRAMES)})
    assert row.task_metrics['streaming_miou'] == pytest.approx(miou)
    assert row.task_metrics['streaming_pixel_accuracy'] == pytest.approx(accuracy)
    if behind == 0:
        assert row.miou == pytest.approx(1.0)
        assert row.task_metrics['streaming_miou'] == row.miou
    else:
        assert row.miou == pytest.approx(1.0)
        assert miou < 0.95
