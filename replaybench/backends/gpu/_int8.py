"""``tensorrt --precision int8``: the INT8 calibration cache TensorRT builds its engine with.

Two kinds of model:

* a model ``replaybench quantize`` wrote (QuantizeLinear / DequantizeLinear nodes): TensorRT
  takes its scales as they are (explicit quantisation); they were computed on the bag's frames
  that its ``replaybench.quantization`` metadata names, so no cache is needed;
* a float model: ``calibration_bag`` (and ``calibration_frames``, default 100) names the bag;
  the same frames ``replaybench quantize`` would take (``replaybench.detector.calibration``),
  through the model's preprocessing (``Letterboxer``, the CPU twin of the pipeline's), are fed
  one by one to an ``IInt8EntropyCalibrator2`` (``entropy_calibrator``) while TensorRT builds a
  network of the model; TensorRT writes the cache, which onnxruntime's TensorRT provider then
  reads as its native calibration table (``trt_int8_use_native_calibration_table``).

The TensorRT and torch modules are passed in, so the CPU tests drive the same code with
stand-ins for TensorRT's classes and torch CPU tensors.
"""

from __future__ import annotations

import hashlib
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.errors import BackendError

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from replaybench.detector.spec import ModelSpec
    from replaybench.segmentation.spec import SegModelSpec

__all__ = [
    'CACHE_NAME',
    'Holdout',
    'build_calibration_cache',
    'calibration_batches',
    'calibration_id',
    'entropy_calibrator',
    'is_quantized',
    'parse_holdouts',
]

#: The cache's file name in the engine folder (``trt_int8_calibration_table_name``).
CACHE_NAME = 'calibration.cache'


def is_quantized(path: Path) -> bool:
    """Whether the ONNX model at ``path`` holds QuantizeLinear nodes (explicit INT8)."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    return any(n.op_type == 'QuantizeLinear' for n in model.graph.node)


Holdout = tuple[tuple[float, float | None], ...]


def parse_holdouts(text: str) -> Holdout:
    """``calibration_holdout``: comma-separated ``START:END`` or ``START:`` windows in seconds of
    log time from the bag's start (quantize's ``--holdout``); ``ValueError`` naming the window
    otherwise."""
    windows = []
    for part in (p.strip() for p in text.split(',')):
        if not part:
            continue
        start_text, sep, end_text = part.partition(':')
        try:
            start = float(start_text)
            end = float(end_text) if end_text.strip() else None
        except ValueError:
            start, end = -1.0, None
        if not sep or start < 0 or (end is not None and end <= start):
            msg = f'{part!r}: expected START:END or START: in seconds, START >= 0 < END'
            raise ValueError(msg)
        windows.append((start, end))
    return tuple(windows)


def calibration_id(bag: Path, frames: int, holdout: Holdout = ()) -> str:
    """What a calibration cache depends on besides the model: the bag's sha256, ``frames``
    and the held-out windows (none: the id as before they existed)."""
    from replaybench.sources.digest import input_sha256

    windows = ''.join(f':{s:g}-{"" if e is None else f"{e:g}"}' for s, e in holdout)
    return f'{input_sha256(bag)}:{frames}{windows}'


def calibration_batches(
    spec: ModelSpec | SegModelSpec, bag: Path, frames: int, holdout: Holdout = ()
) -> list[np.ndarray]:
    """The calibration frames (none in a ``holdout`` window) as the model's float32 input
    tensors ``[1, 3, H, W]``."""
    from replaybench.detector.calibration import calibration_frames
    from replaybench.detector.preprocess import Letterboxer

    picked = calibration_frames(bag, frames, holdout=holdout)
    letterbox = Letterboxer(spec.preprocess)
    batches = []
    for frame in picked.frames:
        tensor, _ = letterbox(frame.image, frame.encoding)
        batches.append(np.ascontiguousarray(tensor, dtype=np.float32).copy())
    return batches


def entropy_calibrator(
    trt: Any, torch: Any, batches: Sequence[np.ndarray], cache: Path, device: Any
) -> Any:
    """An ``IInt8EntropyCalibrator2`` over ``batches`` (one frame a batch) that reads and
    writes its cache at ``cache``."""

    class EntropyCalibrator(trt.IInt8EntropyCalibrator2):  # type: ignore[misc]
        def __init__(self) -> None:
            trt.IInt8EntropyCalibrator2.__init__(self)
            self.batches = list(batches)
            self.index = 0
            self.device_input: Any = None  # kept alive while TensorRT reads it

        def get_batch_size(self) -> int:
            return 1

        def get_batch(self, names: Sequence[str]) -> list[int] | None:
            if self.index >= len(self.batches):
                return None
            host = torch.from_numpy(self.batches[self.index])
            self.device_input = host.to(device)
            self.index += 1
            return [int(self.device_input.data_ptr())] * len(names)

        def read_calibration_cache(self) -> bytes | None:
            return cache.read_bytes() if cache.is_file() else None

        def write_calibration_cache(self, data: Any) -> None:
            cache.write_bytes(bytes(data))

    return EntropyCalibrator()


def build_calibration_cache(
    trt: Any, torch: Any, model: Path, batches: Sequence[np.ndarray], cache: Path, device: Any
) -> Path:
    """Build an INT8 network of ``model`` with the calibrator so that TensorRT writes
    ``cache``; the engine itself is thrown away (onnxruntime builds its own with the cache)."""
    if cache.is_file():
        return cache
    if not batches:
        msg = 'tensorrt: no calibration frame to build the INT8 calibration cache from'
        raise BackendError(msg)
    logger = trt.Logger(trt.Logger.WARNING)
    builder = trt.Builder(logger)
    network = builder.create_network(0)
    parser = trt.OnnxParser(network, logger)
    if not parser.parse(model.read_bytes()):
        errors = '; '.join(str(parser.get_error(i)) for i in range(parser.num_errors))
        msg = f'tensorrt: cannot parse {model} for INT8 calibration: {errors or "unknown error"}'
        raise BackendError(msg)
    config = builder.create_builder_config()
    config.set_flag(trt.BuilderFlag.INT8)
    calibrator = entropy_calibrator(trt, torch, batches, cache, device)
    config.int8_calibrator = calibrator
    built = builder.build_serialized_network(network, config)
    if built is None or not cache.is_file():
        msg = f'tensorrt: TensorRT wrote no INT8 calibration cache for {model}'
        raise BackendError(msg)
    return cache


def cache_digest(cache: Path) -> str:
    """16 hex digits of the cache's sha256 (run.json names the cache it ran with)."""
    return hashlib.sha256(cache.read_bytes()).hexdigest()[:16]
