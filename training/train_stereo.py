"""Train the bundled ``stereo_small`` disparity model on generated pairs and export it as ONNX.

Usage (from the repository root, with the ``train`` extra installed)::

    python training/train_stereo.py --out replaybench/models/stereo_small.onnx

Training pairs come from ``replaybench.fixtures.stereo_scenes.random_pair`` with seeds
``1..SCENES`` (random planes, textures and depths, exact sub-pixel disparity), as random
crops of 320x240 scenes. The held-out figures are measured on ``HELD_OUT_SEEDS`` (whole
320x240 pairs, never trained on) and on the stereo fixture's pairs (``fixtures/stereo.py``,
another scene again), and written into the model's metadata. Seeded; one or two threads.

Model (``STEREO_SIZE`` input, grey / 255, two inputs ``left`` and ``right`` ``[1,1,H,W]``):
shared features (five 3x3 convolutions, two of stride 2) at 1/4 resolution; a group-wise
correlation cost volume over ``LEVELS`` disparities (0, 4, ... px) at 1/4 resolution; three
3D convolutions over it; soft-argmin; bilinear upsampling x4 (values x4); a small residual
refinement at full resolution from the left image and that disparity. Output ``disparity``
``[1,1,H,W]`` float32 pixels of the input.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from replaybench.fixtures.stereo_scenes import HELD_OUT_SEEDS, random_pair

if TYPE_CHECKING:
    import torch

SCENES = 200_000
SIZE = (320, 240)  # the exported input: width, height
CROP = (160, 96)
LEVELS = 16  # quarter-resolution disparities 0..15: 0..60 px at the input's size
GROUPS = 4
if HELD_OUT_SEEDS.start <= SCENES:
    msg = f'training seeds 1..{SCENES} would include the held-out seeds'
    raise SystemExit(msg)


def build() -> torch.nn.Module:
    import torch
    from torch import nn

    def conv(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Module:
        return nn.Sequential(
            nn.Conv2d(cin, cout, 3, stride=stride, padding=dilation, dilation=dilation),
            nn.LeakyReLU(0.1),
        )

    class StereoNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.features = nn.Sequential(
                conv(1, 16, 2),
                conv(16, 16),
                conv(16, 32, 2),
                conv(32, 32),
                conv(32, 32, dilation=2),
                nn.Conv2d(32, 32, 3, padding=1),
            )
            self.aggregate = nn.Sequential(
                nn.Conv3d(GROUPS, 8, 3, padding=1),
                nn.LeakyReLU(0.1),
                nn.Conv3d(8, 8, 3, padding=1),
                nn.LeakyReLU(0.1),
                nn.Conv3d(8, 1, 3, padding=1),
            )
            self.refine = nn.Sequential(
                conv(2, 12),
                conv(12, 12, dilation=2),
                conv(12, 12, dilation=4),
                conv(12, 12),
                nn.Conv2d(12, 1, 3, padding=1),
            )
            self.register_buffer(
                'levels', torch.arange(LEVELS, dtype=torch.float32).view(1, LEVELS, 1, 1)
            )

        def coarse(self, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
            n = left.shape[0]
            fl = self.features(left - 0.5)
            fr = self.features(right - 0.5)
            c, h, w = fl.shape[1:]
            # group-wise cosine correlation: each group's features normalised to length 1
            fl = fl.view(n, GROUPS, c // GROUPS, h, w)
            fr = fr.view(n, GROUPS, c // GROUPS, h, w)
            fl = fl / (fl.pow(2).sum(dim=2, keepdim=True) + 1e-6).sqrt()
            fr = fr / (fr.pow(2).sum(dim=2, keepdim=True) + 1e-6).sqrt()
            costs = []
            for d in range(LEVELS):
                shifted = nn.functional.pad(fr[..., : w - d], (d, 0)) if d else fr
                costs.append((fl * shifted).sum(dim=2) * 8.0)
            volume = torch.stack(costs, dim=2)  # n, groups, levels, h, w
            logits = self.aggregate(volume).squeeze(1)
            prob = torch.softmax(logits, dim=1)
            quarter = (prob * self.levels).sum(dim=1, keepdim=True)
            return nn.functional.interpolate(
                quarter * 4.0, scale_factor=4.0, mode='bilinear', align_corners=False
            )

        def forward(self, left: torch.Tensor, right: torch.Tensor) -> torch.Tensor:
            up = self.coarse(left, right)
            return up + self.refine(torch.cat([left - 0.5, up / 32.0], dim=1))

    torch.manual_seed(0)
    return StereoNet()


def batch(rng: np.random.Generator, size: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    import torch

    lefts, rights, truths = [], [], []
    for _ in range(size):
        x0 = int(rng.integers(0, SIZE[0] - CROP[0] + 1))
        y0 = int(rng.integers(0, SIZE[1] - CROP[1] + 1))
        pair = random_pair(int(rng.integers(1, SCENES + 1)), SIZE, (x0, y0, *CROP))
        lefts.append(pair.left)
        rights.append(pair.right)
        truths.append(pair.disparity)

    def stack(items: list[np.ndarray], scale: float) -> torch.Tensor:
        return torch.from_numpy(np.stack(items)[:, None].astype(np.float32) * np.float32(scale))

    return stack(lefts, 1 / 255), stack(rights, 1 / 255), stack(truths, 1.0)


def train(
    seed: int, steps: int, size: int, lr: float, log_every: int, threads: int
) -> torch.nn.Module:
    import torch

    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    rng = np.random.default_rng(seed)
    model = build()
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    smooth = torch.nn.functional.smooth_l1_loss
    for step in range(1, steps + 1):
        left, right, truth = batch(rng, size)
        up = model.coarse(left, right)
        out = up + model.refine(torch.cat([left - 0.5, up / 32.0], dim=1))
        loss = 0.5 * smooth(up, truth) + smooth(out, truth)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % log_every == 0 or step == steps:
            epe = (out - truth).abs().mean().item()
            print(f'step {step}/{steps} loss {loss.item():.4f} epe {epe:.3f}', flush=True)
    return model.eval()


def held_out(path: Path) -> dict[str, float]:
    """EPE and bad-2 of the exported model on the held-out pairs and the stereo fixture."""
    import onnxruntime as ort

    from replaybench.fixtures.stereo import render_stereo
    from replaybench.stereo.metrics import DisparityCounts, score_disparity

    session = ort.InferenceSession(str(path), providers=['CPUExecutionProvider'])

    def run(left: np.ndarray, right: np.ndarray) -> np.ndarray:
        feed = {
            'left': left[None, None].astype(np.float32) / np.float32(255),
            'right': right[None, None].astype(np.float32) / np.float32(255),
        }
        return np.asarray(session.run(['disparity'], feed)[0][0, 0])

    figures = {}
    for name, pairs in (
        ('held_out', [random_pair(s, SIZE) for s in HELD_OUT_SEEDS]),
        ('fixture', [render_stereo(SIZE, i) for i in range(16)]),
    ):
        total = DisparityCounts()
        for pair in pairs:
            total += score_disparity(run(pair.left, pair.right), pair.disparity)
        result = total.figures()
        assert result.epe is not None
        assert result.bad2 is not None
        figures[f'{name}_epe'] = round(result.epe, 4)
        figures[f'{name}_bad2'] = round(result.bad2, 4)
    return figures


def export(model: torch.nn.Module, out: Path, seed: int, steps: int) -> None:
    """Export to ONNX (opset 17, legacy exporter), then add the held-out figures as metadata."""
    import tempfile

    import onnx
    import torch

    width, height = SIZE
    with tempfile.TemporaryDirectory() as tmp:
        exported = Path(tmp) / 'model.onnx'
        zeros = torch.zeros(1, 1, height, width)
        torch.onnx.export(
            model,
            (zeros, zeros),
            exported,
            input_names=['left', 'right'],
            output_names=['disparity'],
            opset_version=17,
            do_constant_folding=True,
            dynamo=False,
        )
        proto = onnx.load(exported)
    onnx.checker.check_model(proto)
    meta = {
        'replaybench.stereo_layout': 'two-inputs',
        'replaybench.channel_order': 'grey',
        'replaybench.scale': repr(1 / 255),
        'replaybench.max_disparity': str(4 * (LEVELS - 1)),
        'replaybench.trained_on': (
            f'replaybench.fixtures.stereo_scenes seeds 1..{SCENES}, {CROP[0]}x{CROP[1]} crops '
            f'of {width}x{height}; training seed {seed}, {steps} steps'
        ),
    }
    del proto.metadata_props[:]
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.doc_string = 'replaybench stereo_small: left-image disparity in pixels from a grey pair'
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(proto.SerializeToString(deterministic=True))
    figures = held_out(out)
    seeds = f'{HELD_OUT_SEEDS.start}..{HELD_OUT_SEEDS.stop - 1}'
    for key, value in figures.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = f'replaybench.{key}', repr(value)
    entry = proto.metadata_props.add()
    entry.key = 'replaybench.held_out'
    entry.value = (
        f'held_out: replaybench.fixtures.stereo_scenes seeds {seeds} at {width}x{height}; '
        f'fixture: replaybench.fixtures.stereo render_stereo frames 0..15 at {width}x{height}; '
        'pooled EPE (px) and bad-2 (share of truth pixels with error > 2 px)'
    )
    out.write_bytes(proto.SerializeToString(deterministic=True))
    print('held out:', figures)


def _motorcycle_set(root: Path) -> tuple[object, np.ndarray] | None:
    """The Middlebury Motorcycle pair (PROVENANCE.md section 6) as a rectified FrameSet."""
    import cv2

    from replaybench.types import CameraInfo, Frame, FrameSet

    folder = root / 'stereo' / 'motorcycle'
    if not (folder / 'motorcycle_disp.npz').is_file():
        return None
    left = cv2.imread(str(folder / 'motorcycle_left.png'), cv2.IMREAD_COLOR)
    right = cv2.imread(str(folder / 'motorcycle_right.png'), cv2.IMREAD_COLOR)
    truth = np.load(folder / 'motorcycle_disp.npz')['arr_0'].astype(np.float32)
    f, cx, cy, doffs, baseline = 994.978, 311.193, 254.877, 31.086, 0.193001
    height, width = truth.shape
    eye = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    frames = []
    for side, image, ccx, tx in (
        ('left', left, cx, 0.0),
        ('right', right, cx + doffs, -f * baseline),
    ):
        k = (f, 0.0, ccx, 0.0, f, cy, 0.0, 0.0, 1.0)
        p = (f, 0.0, ccx, tx, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0)
        info = CameraInfo(0, side, width, height, 'plumb_bob', (0.0,) * 5, k, eye, p)
        frames.append(
            Frame(f'/m/{side}/image_rect', 0, 0, 0, side, image, 'bgr8', 'bgr8', False, info)
        )
    return FrameSet(tuple(frames)), truth


def evaluate(path: Path, real: Path) -> None:
    """The model through onnx-stereo beside sgbm (stereo_image_proc's defaults) on the
    held-out pairs, the stereo fixture and the Middlebury Motorcycle pair (where present)."""
    from replaybench.backends.base import BackendOptions
    from replaybench.backends.onnx_stereo import OnnxStereoBackend
    from replaybench.backends.sgbm import SgbmBackend
    from replaybench.fixtures.stereo import rectified_camera_infos, render_stereo
    from replaybench.stereo import DisparityCounts, score_disparity
    from replaybench.types import Frame, FrameSet

    def pair_set(left: np.ndarray, right: np.ndarray) -> FrameSet:
        infos = rectified_camera_infos(SIZE, 0)
        return FrameSet(
            tuple(
                Frame(f'/s/{s}/image_rect', 0, 0, 0, i.frame_id, im, 'mono8', 'mono8', False, i)
                for s, im, i in zip(('left', 'right'), (left, right), infos, strict=True)
            )
        )

    data = {
        'held out (24 pairs)': [
            (pair_set(p.left, p.right), p.disparity)
            for p in (random_pair(s, SIZE) for s in HELD_OUT_SEEDS)
        ],
        'fixture (16 pairs)': [
            (pair_set(v.left, v.right), v.disparity)
            for v in (render_stereo(SIZE, i) for i in range(16))
        ],
    }
    moto = _motorcycle_set(real)
    if moto is not None:
        data['Motorcycle 741x500'] = [moto]
    backends = {
        'onnx-stereo': OnnxStereoBackend(BackendOptions(model=path, threads=1)),
        'sgbm': SgbmBackend(BackendOptions()),
    }
    for name, sets in data.items():
        for label, backend in backends.items():
            total = DisparityCounts()
            for frame_set, truth in sets:
                out = backend.detect(frame_set).output
                total += score_disparity(out.disparity, truth, min_disparity=out.min_disparity)
            f = total.figures()
            print(
                f'{name:22s} {label:12s} EPE {f.epe:.3f} bad-2 {f.bad2:.3f} '
                f'D1-all {f.d1_all:.3f} density {f.density:.3f}'
            )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path('replaybench/models/stereo_small.onnx'))
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--steps', type=int, default=500)
    parser.add_argument('--batch', type=int, default=4)
    parser.add_argument('--lr', type=float, default=1e-3)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--log-every', type=int, default=100)
    parser.add_argument('--evaluate', action='store_true', help='score --out beside sgbm')
    parser.add_argument('--real', type=Path, default=Path('../shared/real'))
    args = parser.parse_args(argv)
    if args.steps:
        start, cpu_start = time.perf_counter(), time.process_time()
        model = train(args.seed, args.steps, args.batch, args.lr, args.log_every, args.threads)
        export(model, args.out, args.seed, args.steps)
        digest = hashlib.sha256(args.out.read_bytes()).hexdigest()
        print(f'wrote {args.out} ({args.out.stat().st_size} bytes, sha256 {digest})')
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
        print(f'total {wall:.0f}s wall, {cpu:.0f}s process CPU')
    if args.evaluate:
        evaluate(args.out, args.real)
    return 0


if __name__ == '__main__':
    sys.exit(main())
