"""Train the bundled ``blobs`` detector on synthetic scenes and export it as ONNX.

Usage (from the repository root, with the ``train`` extra installed)::

    python training/train_blobs.py --out replaybench/models/blobs.onnx

Training frames come from ``replaybench.fixtures.scene.Scene`` with seeds ``1..SCENES`` and
cameras ``0..3``; the committed fixture bags use ``DEFAULT_SEED`` (20240601), so they stay
held out. Everything is seeded and runs with two threads and deterministic algorithms: the
same arguments give the same weights and the same ONNX bytes.

Model: a small fully convolutional detector, one output level at stride 8 with context from a
stride-16 branch; per cell the distances to the box sides (FCOS style, centre sampling) and
one score per class trained with a quality focal loss whose targets are the IoU of the
predicted box. The exported graph decodes the boxes itself and writes the YOLOv8 layout.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from blobs_common import INPUT_SIZE, PAD_VALUE, STRIDE, letterbox

from replaybench.fixtures.scene import CLASS_NAMES, DEFAULT_SEED, Scene

if TYPE_CHECKING:
    import numpy.typing as npt
    import torch

SCENES = 4000
CAMERAS = 4
FRAMES = 1000
FRAMES_PER_SCENE = 2  # frames per scene in a batch (building a scene costs 4 renders)
#: Render sizes: native 320x240 most of the time, other sizes and aspect ratios for scale.
SIZES = ((320, 240),) * 6 + (
    (256, 192),
    (384, 288),
    (400, 300),
    (320, 180),
    (240, 320),
    (480, 360),
    (288, 288),
    (640, 480),
)
if SCENES >= DEFAULT_SEED:  # the fixture bags' scenes must stay out of training
    msg = f'training seeds 1..{SCENES} would include the fixture seed {DEFAULT_SEED}'
    raise SystemExit(msg)
GRID = INPUT_SIZE // STRIDE
CENTRE_RADIUS = 2.5  # strides
NUM_CLASSES = len(CLASS_NAMES)


def pick_scene(rng: np.random.Generator) -> Scene:
    """A random training scene: seed ``1..SCENES``, camera ``0..CAMERAS-1``, size from SIZES."""
    seed = int(rng.integers(1, SCENES + 1))
    camera = int(rng.integers(0, CAMERAS))
    return Scene(SIZES[int(rng.integers(len(SIZES)))], camera, seed)


def sample(
    rng: np.random.Generator, scene: Scene
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32], npt.NDArray[np.int64]]:
    """One augmented frame (RGB model input) with its boxes (xyxy, input px) and classes."""
    import cv2

    size = scene.size
    bgr, truth = scene.render(int(rng.integers(0, FRAMES)))
    boxes = np.array([(d.x0, d.y0, d.x1, d.y1) for d in truth], dtype=np.float32).reshape(-1, 4)
    classes = np.array([d.class_index for d in truth], dtype=np.int64)
    if rng.random() < 0.5:
        bgr = bgr[:, ::-1]
        boxes = np.stack(
            [size[0] - boxes[:, 2], boxes[:, 1], size[0] - boxes[:, 0], boxes[:, 3]], axis=1
        )
    if rng.random() < 0.5:
        gain, bias = float(rng.uniform(0.8, 1.2)), float(rng.uniform(-20.0, 20.0))
        bgr = np.clip(bgr.astype(np.float32) * gain + bias, 0, 255).astype(np.uint8)
    if rng.random() < 0.3:
        quality = int(rng.integers(60, 96))
        _, jpeg = cv2.imencode(
            '.jpg', np.ascontiguousarray(bgr), [cv2.IMWRITE_JPEG_QUALITY, quality]
        )
        bgr = np.asarray(cv2.imdecode(jpeg, cv2.IMREAD_COLOR), dtype=np.uint8)
    image, box = letterbox(np.ascontiguousarray(bgr))
    boxes = boxes * box.scale + np.array([box.pad_x, box.pad_y] * 2, dtype=np.float32)
    return image, boxes.astype(np.float32), classes


_CELLS = (np.arange(GRID, dtype=np.float32) + 0.5) * STRIDE
CELL_X = np.tile(_CELLS, GRID)
CELL_Y = np.repeat(_CELLS, GRID)


def assign(boxes: npt.NDArray[np.float32]) -> npt.NDArray[np.int64]:
    """Ground-truth index per cell (row-major, ``GRID * GRID``), -1 for background.

    A cell is positive for a box when its centre lies inside the box and within
    ``CENTRE_RADIUS`` strides of the box centre; the cell holding the box centre always is.
    Cells claimed by several boxes go to the smallest.
    """
    n = GRID * GRID
    if len(boxes) == 0:
        return np.full(n, -1, dtype=np.int64)
    x0, y0, x1, y1 = (boxes[:, k][:, None] for k in range(4))
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    gx, gy = CELL_X[None, :], CELL_Y[None, :]
    radius = CENTRE_RADIUS * STRIDE
    inside = (gx > x0) & (gx < x1) & (gy > y0) & (gy < y1)
    near = (np.abs(gx - cx) < radius) & (np.abs(gy - cy) < radius)
    positive = inside & near
    col = np.clip((cx[:, 0] // STRIDE).astype(np.int64), 0, GRID - 1)
    row = np.clip((cy[:, 0] // STRIDE).astype(np.int64), 0, GRID - 1)
    positive[np.arange(len(boxes)), row * GRID + col] = True
    area = ((x1 - x0) * (y1 - y0))[:, 0]
    cost = np.where(positive, area[:, None], np.inf)
    best = cost.argmin(axis=0)
    return np.where(np.isfinite(cost.min(axis=0)), best, -1).astype(np.int64)


def batch(
    rng: np.random.Generator, size: int
) -> tuple[
    npt.NDArray[np.uint8], npt.NDArray[np.int64], npt.NDArray[np.float32], npt.NDArray[np.int64]
]:
    """Images NCHW uint8, per-cell gt box index into the flat box list, boxes, classes."""
    images, owners, all_boxes, all_classes = [], [], [], []
    offset = 0
    scene = pick_scene(rng)
    for k in range(size):
        if k and k % FRAMES_PER_SCENE == 0:
            scene = pick_scene(rng)
        image, boxes, classes = sample(rng, scene)
        owner = assign(boxes)
        images.append(image.transpose(2, 0, 1))
        owners.append(np.where(owner >= 0, owner + offset, -1))
        all_boxes.append(boxes)
        all_classes.append(classes)
        offset += len(boxes)
    return (
        np.stack(images),
        np.stack(owners),
        np.concatenate(all_boxes).reshape(-1, 4),
        np.concatenate(all_classes),
    )


def build_model() -> torch.nn.Module:
    import torch
    from torch import nn
    from torch.nn import functional as F  # noqa: N812

    def cbr(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
        return nn.Sequential(
            nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU()
        )

    class Blobs(nn.Module):
        """Raw head: ``[B, 4 + C, GRID, GRID]`` (side distances before softplus, logits)."""

        def __init__(self) -> None:
            super().__init__()
            self.stem = nn.Sequential(
                cbr(3, 16, 2), cbr(16, 24, 2), cbr(24, 24), cbr(24, 48, 2), cbr(48, 48), cbr(48, 48)
            )
            self.context = nn.Sequential(cbr(48, 64, 2), cbr(64, 64), cbr(64, 64))
            self.lateral = nn.Sequential(nn.Conv2d(64, 48, 1, bias=False), nn.BatchNorm2d(48))
            self.head = nn.Sequential(cbr(48, 48), cbr(48, 48))
            self.out = nn.Conv2d(48, 4 + NUM_CLASSES, 1)
            prior = 0.01
            bias = self.out.bias
            assert bias is not None
            nn.init.constant_(bias[4:], -math.log((1 - prior) / prior))
            nn.init.constant_(bias[:4], 0.5)
            self.register_buffer('cell_x', torch.from_numpy(CELL_X), persistent=False)
            self.register_buffer('cell_y', torch.from_numpy(CELL_Y), persistent=False)

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            c3 = self.stem(x)
            c4 = self.context(c3)
            up = F.interpolate(self.lateral(c4), scale_factor=2.0, mode='nearest')
            raw: torch.Tensor = self.out(self.head(F.relu(c3 + up)))
            return raw

    return Blobs()


def decode(model: torch.nn.Module, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Raw head -> (boxes xyxy ``[B, N, 4]`` in input pixels, logits ``[B, N, C]``)."""
    import torch
    from torch.nn import functional as F  # noqa: N812

    flat = raw.flatten(2).transpose(1, 2)  # B, N, 4 + C
    dist = F.softplus(flat[..., :4]) * STRIDE
    gx, gy = cast('torch.Tensor', model.cell_x), cast('torch.Tensor', model.cell_y)
    boxes = torch.stack(
        [gx - dist[..., 0], gy - dist[..., 1], gx + dist[..., 2], gy + dist[..., 3]], dim=-1
    )
    return boxes, flat[..., 4:]


def box_iou_giou(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """IoU and GIoU of matching rows of two ``[M, 4]`` xyxy tensors."""
    import torch

    iw = (torch.minimum(a[:, 2], b[:, 2]) - torch.maximum(a[:, 0], b[:, 0])).clamp(min=0)
    ih = (torch.minimum(a[:, 3], b[:, 3]) - torch.maximum(a[:, 1], b[:, 1])).clamp(min=0)
    inter = iw * ih
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a + area_b - inter + 1e-6
    iou = inter / union
    cw = torch.maximum(a[:, 2], b[:, 2]) - torch.minimum(a[:, 0], b[:, 0])
    ch = torch.maximum(a[:, 3], b[:, 3]) - torch.minimum(a[:, 1], b[:, 1])
    hull = cw * ch + 1e-6
    return iou, iou - (hull - union) / hull


def loss_fn(
    model: torch.nn.Module,
    raw: torch.Tensor,
    owners: torch.Tensor,
    gt_boxes: torch.Tensor,
    gt_classes: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Quality focal loss (IoU targets) + GIoU loss over positive cells; (total, cls, box)."""
    import torch
    from torch.nn import functional as F  # noqa: N812

    boxes, logits = decode(model, raw)
    pos = owners >= 0
    n_pos = max(int(pos.sum()), 1)
    owner = owners[pos]
    pred = boxes[pos]
    target_boxes = gt_boxes[owner]
    iou, giou = box_iou_giou(pred, target_boxes)
    target = torch.zeros_like(logits)
    target[pos, gt_classes[owner]] = iou.detach().clamp(min=0.0)
    prob = logits.sigmoid()
    bce = F.binary_cross_entropy_with_logits(logits, target, reduction='none')
    cls_loss = (bce * (prob - target).abs().pow(2)).sum() / n_pos
    box_loss = (1.0 - giou).sum() / n_pos
    return cls_loss + 2.0 * box_loss, cls_loss, box_loss


def yolov8_layout(model: torch.nn.Module) -> torch.nn.Module:
    """Wrap the raw model: ``images`` -> ``[1, 4 + C, N]`` (cx, cy, w, h, class scores)."""
    import torch
    from torch import nn

    class Yolov8Layout(nn.Module):
        def __init__(self, inner: nn.Module) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, images: torch.Tensor) -> torch.Tensor:
            boxes, logits = decode(self.inner, self.inner(images))
            xy = (boxes[..., :2] + boxes[..., 2:]) / 2
            wh = boxes[..., 2:] - boxes[..., :2]
            return torch.cat([xy, wh, logits.sigmoid()], dim=-1).transpose(1, 2)

    return Yolov8Layout(model)


def export(model: torch.nn.Module, out: Path, seed: int) -> None:
    """Export to ONNX (opset 17, legacy exporter) and write the replaybench metadata."""
    import tempfile

    import onnx
    import torch

    wrapper = yolov8_layout(model).eval()
    with tempfile.TemporaryDirectory() as tmp:
        exported = Path(tmp) / 'exported.onnx'
        torch.onnx.export(
            wrapper,
            (torch.zeros(1, 3, INPUT_SIZE, INPUT_SIZE),),
            exported,
            input_names=['images'],
            output_names=['output0'],
            opset_version=17,
            do_constant_folding=True,
            dynamo=False,
        )
        proto = onnx.load(exported)
    onnx.checker.check_model(proto)
    meta = {
        'replaybench.family': 'yolov8',
        'names': ','.join(CLASS_NAMES),
        'replaybench.channel_order': 'rgb',
        'replaybench.scale': repr(1 / 255),
        'replaybench.pad_value': str(PAD_VALUE),
        'replaybench.letterbox_align': 'center',
        'replaybench.input_size': f'{INPUT_SIZE}x{INPUT_SIZE}',
        'replaybench.trained_on': (
            f'replaybench.fixtures.scene seeds 1..{SCENES} cameras 0..{CAMERAS - 1} '
            f'frames 0..{FRAMES - 1}; training seed {seed}'
        ),
    }
    del proto.metadata_props[:]
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.doc_string = 'replaybench blobs detector: red, green, blue, yellow colour objects'
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(proto.SerializeToString(deterministic=True))


def train(seed: int, steps: int, batch_size: int, lr: float, log_every: int) -> torch.nn.Module:
    import cv2
    import torch

    cv2.setNumThreads(1)
    torch.set_num_threads(2)
    torch.manual_seed(seed)
    torch.use_deterministic_algorithms(True)
    rng = np.random.default_rng(seed)
    model = build_model()
    n_params = sum(p.numel() for p in model.parameters())
    print(f'params {n_params}', flush=True)
    decay = [p for p in model.parameters() if p.ndim > 1]
    no_decay = [p for p in model.parameters() if p.ndim <= 1]
    optimiser = torch.optim.AdamW(
        [{'params': decay, 'weight_decay': 1e-4}, {'params': no_decay, 'weight_decay': 0.0}], lr=lr
    )
    warmup = max(1, steps // 20)

    def schedule(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        progress = (step - warmup) / max(1, steps - warmup)
        return 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * progress))

    scheduler = torch.optim.lr_scheduler.LambdaLR(optimiser, schedule)
    model.train()
    start = time.perf_counter()
    totals = np.zeros(3)
    for step in range(steps):
        images, owners, boxes, classes = batch(rng, batch_size)
        x = torch.from_numpy(images).float() / 255.0
        raw = model(x)
        loss, cls_loss, box_loss = loss_fn(
            model, raw, torch.from_numpy(owners), torch.from_numpy(boxes), torch.from_numpy(classes)
        )
        optimiser.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]
        optimiser.step()
        scheduler.step()
        totals += (loss.item(), cls_loss.item(), box_loss.item())
        if (step + 1) % log_every == 0 or step + 1 == steps:
            n = (step % log_every) + 1
            mean = totals / n
            elapsed = time.perf_counter() - start
            print(
                f'step {step + 1}/{steps} loss {mean[0]:.4f} cls {mean[1]:.4f} '
                f'box {mean[2]:.4f} lr {scheduler.get_last_lr()[0]:.5f} {elapsed:.0f}s',
                flush=True,
            )
            totals[:] = 0
    model.eval()
    return model


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path('replaybench/models/blobs.onnx'))
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--steps', type=int, default=800)
    parser.add_argument('--batch', type=int, default=16)
    parser.add_argument('--lr', type=float, default=3e-3)
    parser.add_argument('--log-every', type=int, default=100)
    args = parser.parse_args(argv)
    start, cpu_start = time.perf_counter(), time.process_time()
    model = train(args.seed, args.steps, args.batch, args.lr, args.log_every)
    export(model, args.out, args.seed)
    digest = hashlib.sha256(args.out.read_bytes()).hexdigest()
    size = args.out.stat().st_size
    print(f'wrote {args.out} ({size} bytes, sha256 {digest})')
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    print(f'total {wall:.0f}s wall, {cpu:.0f}s process CPU')
    return 0


if __name__ == '__main__':
    sys.exit(main())
