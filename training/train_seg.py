"""Train the bundled ``blobs_seg`` segmentation model on synthetic scenes and export it as ONNX.

Usage (from the repository root, with the ``train`` extra installed)::

    python training/train_seg.py --out replaybench/models/blobs_seg.onnx

Training frames come from ``replaybench.fixtures.scene.Scene`` with seeds ``1..SCENES`` and
cameras ``0..CAMERAS-1`` at 320x240, the labels from ``replaybench.fixtures.masks``: class id
0 background, 1..4 red, green, blue, yellow. The committed fixture bags use ``DEFAULT_SEED``
(20240601), so they stay held out (``--evaluate`` scores them). Everything is seeded and runs
on one thread with deterministic algorithms.

Model: four 3x3 convolutions (two of stride 2, one dilated) and a 1x1 classifier, logits at
stride 4, upsampled bilinearly to the input inside the graph: output ``[1, 5, 240, 320]``
class scores (``logits-nchw``), input ``[1, 3, 240, 320]`` RGB / 255, stretched.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replaybench.fixtures.masks import MASK_CLASS_NAMES, semantic_labels
from replaybench.fixtures.scene import DEFAULT_SEED, Scene

if TYPE_CHECKING:
    import numpy.typing as npt
    import torch

SCENES = 400
CAMERAS = 4
FRAMES = 600
SIZE = (320, 240)  # input width, height
NUM_CLASSES = len(MASK_CLASS_NAMES)
#: Background is most of every frame: its loss weight is lowered so objects are not ignored.
CLASS_WEIGHTS = (0.3, 1.0, 1.0, 1.0, 1.0)
if SCENES >= DEFAULT_SEED:  # the fixture bags' scenes must stay out of training
    msg = f'training seeds 1..{SCENES} would include the fixture seed {DEFAULT_SEED}'
    raise SystemExit(msg)


def sample(rng: np.random.Generator) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
    """One augmented frame (RGB, HxWx3) and its label mask."""
    import cv2

    scene = Scene(SIZE, int(rng.integers(0, CAMERAS)), int(rng.integers(1, SCENES + 1)))
    index = int(rng.integers(0, FRAMES))
    bgr, _ = scene.render(index)
    labels = semantic_labels(scene, index)
    if rng.random() < 0.5:
        bgr, labels = bgr[:, ::-1], labels[:, ::-1]
    if rng.random() < 0.5:
        gain, bias = float(rng.uniform(0.8, 1.2)), float(rng.uniform(-20.0, 20.0))
        bgr = np.clip(bgr.astype(np.float32) * gain + bias, 0, 255).astype(np.uint8)
    if rng.random() < 0.3:
        quality = int(rng.integers(60, 96))
        _, jpeg = cv2.imencode(
            '.jpg', np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, quality]
        )
        bgr = np.asarray(cv2.imdecode(jpeg, cv2.IMREAD_COLOR), dtype=np.uint8)
    return np.ascontiguousarray(bgr[:, :, ::-1]), np.ascontiguousarray(labels)


def build() -> torch.nn.Module:
    import torch
    from torch import nn

    class SegNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.body = nn.Sequential(
                nn.Conv2d(3, 16, 3, stride=2, padding=1),
                nn.ReLU(),
                nn.Conv2d(16, 16, 3, padding=1),
                nn.ReLU(),
                nn.Conv2d(16, 24, 3, stride=2, padding=1),
                nn.ReLU(),
                nn.Conv2d(24, 24, 3, padding=2, dilation=2),
                nn.ReLU(),
                nn.Conv2d(24, NUM_CLASSES, 1),
            )

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            logits = self.body(x)
            return nn.functional.interpolate(
                logits, size=x.shape[-2:], mode='bilinear', align_corners=False
            )

    torch.manual_seed(0)
    return SegNet()


def train(seed: int, steps: int, batch: int, lr: float, log_every: int) -> torch.nn.Module:
    import torch

    torch.manual_seed(seed)
    torch.set_num_threads(1)
    torch.use_deterministic_algorithms(True)
    rng = np.random.default_rng(seed)
    model = build()
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    weights = torch.tensor(CLASS_WEIGHTS)
    for step in range(1, steps + 1):
        pairs = [sample(rng) for _ in range(batch)]
        images = torch.from_numpy(np.stack([p[0] for p in pairs])).permute(0, 3, 1, 2)
        labels = torch.from_numpy(np.stack([p[1] for p in pairs]).astype(np.int64))
        logits = model(images.float() / 255.0)
        loss = torch.nn.functional.cross_entropy(logits, labels, weight=weights)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % log_every == 0 or step == steps:
            print(f'step {step}/{steps} loss {loss.item():.4f}', flush=True)
    return model.eval()


def export(model: torch.nn.Module, out: Path, seed: int, steps: int) -> None:
    """Export to ONNX (opset 17, legacy exporter) with the replaybench metadata."""
    import json
    import tempfile

    import onnx
    import torch

    with tempfile.TemporaryDirectory() as tmp:
        exported = Path(tmp) / 'model.onnx'
        torch.onnx.export(
            model,
            (torch.zeros(1, 3, SIZE[1], SIZE[0]),),
            exported,
            input_names=['images'],
            output_names=['logits'],
            opset_version=17,
            do_constant_folding=True,
            dynamo=False,
        )
        proto = onnx.load(exported)
    onnx.checker.check_model(proto)
    meta = {
        'replaybench.seg_layout': 'logits-nchw',
        'names': json.dumps(list(MASK_CLASS_NAMES)),
        'replaybench.channel_order': 'rgb',
        'replaybench.scale': repr(1 / 255),
        'replaybench.letterbox': 'false',
        'replaybench.trained_on': (
            f'replaybench.fixtures.scene seeds 1..{SCENES} cameras 0..{CAMERAS - 1} '
            f'frames 0..{FRAMES - 1} at {SIZE[0]}x{SIZE[1]}; training seed {seed}, {steps} steps'
        ),
    }
    del proto.metadata_props[:]
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.doc_string = 'replaybench blobs_seg: background, red, green, blue, yellow per pixel'
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(proto.SerializeToString(deterministic=True))


def evaluate(path: Path, frames: int) -> None:
    """mIoU of the model through onnx-seg on held-out frames (the fixture seed, camera 0)."""
    from replaybench.backends.base import BackendOptions
    from replaybench.backends.onnx_seg import OnnxSegBackend
    from replaybench.tasks.segmentation.scoring import confusion, scores
    from replaybench.types import Frame

    backend = OnnxSegBackend(BackendOptions(model=path, threads=1))
    backend.open()
    total = np.zeros((256, 256), dtype=np.int64)
    for camera in (0, 1):
        scene = Scene(SIZE, camera, DEFAULT_SEED)
        for index in range(frames):
            bgr, _ = scene.render(index)
            frame = Frame('/camera/image_raw', index, 0, 0, 'cam', bgr, 'bgr8', 'bgr8')
            mask = backend.detect(frame).mask
            assert mask is not None
            total += confusion(mask.labels, semantic_labels(scene, index))
    result = scores(total)
    ious = ', '.join(f'{MASK_CLASS_NAMES[c]} {v:.3f}' for c, v in sorted(result.iou.items()))
    print(
        f'held out (seed {DEFAULT_SEED}, cameras 0-1, frames 0..{frames - 1}): '
        f'mIoU {result.miou:.4f}, pixel accuracy {result.pixel_accuracy:.4f}; IoU {ious}'
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path('replaybench/models/blobs_seg.onnx'))
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--steps', type=int, default=300)
    parser.add_argument('--batch', type=int, default=6)
    parser.add_argument('--lr', type=float, default=1e-2)
    parser.add_argument('--log-every', type=int, default=50)
    parser.add_argument('--evaluate', type=int, default=0, metavar='FRAMES')
    args = parser.parse_args(argv)
    if args.steps:
        start, cpu_start = time.perf_counter(), time.process_time()
        model = train(args.seed, args.steps, args.batch, args.lr, args.log_every)
        export(model, args.out, args.seed, args.steps)
        digest = hashlib.sha256(args.out.read_bytes()).hexdigest()
        size = args.out.stat().st_size
        print(f'wrote {args.out} ({size} bytes, sha256 {digest})')
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
        print(f'total {wall:.0f}s wall, {cpu:.0f}s process CPU')
    if args.evaluate:
        evaluate(args.out, args.evaluate)
    return 0


if __name__ == '__main__':
    sys.exit(main())
