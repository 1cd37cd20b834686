"""``replaybench quantize``: static INT8 quantisation of an ONNX model, calibrated on a bag.

The calibration frames are ``frames`` image messages spread evenly over the bag's selected
topics (in replay order), never one whose log time falls in a ``holdout`` window, each fed
through the backend's own preprocessing (``OnnxCpuBackend.inputs`` / ``OnnxSegBackend.inputs``)
so that calibration sees what inference sees. ONNX Runtime's ``quantize_static`` does the rest:
QDQ format, per-channel int8 weights, uint8 activations. The model's opset is upgraded to 13
first when it is older (per-channel QDQ needs it). By default the decode head stays in float:
every node from the last ``Conv`` of each path to an output on (``head_nodes``). The
calibration's provenance goes into the model's metadata (``replaybench.detector.provenance``).

Nothing is written beside the input model: the work happens in a temporary folder and the
result is moved onto ``out`` when it is complete.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench._version import __version__
from replaybench.detector.calibration import (
    QuantizeError,
    calibration_frames,
    calibration_pairs,
)
from replaybench.detector.provenance import PROVENANCE_KEY
from replaybench.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence

__all__ = [
    'METHODS',
    'QuantizeError',
    'QuantizeOutcome',
    'QuantizeSettings',
    'head_nodes',
    'quantize_model',
]

#: ``--method`` values and ONNX Runtime's calibration methods.
METHODS = ('minmax', 'entropy', 'percentile')
#: The opset per-channel QDQ quantisation needs.
MIN_OPSET = 13
#: Operator domains ONNX Runtime's CPU provider runs.
_DOMAINS = frozenset({'', 'ai.onnx', 'com.microsoft', 'ai.onnx.ml'})


@dataclass(frozen=True, slots=True)
class QuantizeSettings:
    """What ``replaybench quantize`` was asked for.

    ``exclude``: None for the default (the decode head in float), ``()`` for none (``--exclude
    none``), else the node names to keep in float. ``holdout``: log-time windows in seconds
    from the bag's first message, ``(start, end)`` with ``end`` None for the rest of the bag.
    """

    model: Path
    bag: Path
    out: Path
    frames: int = 100
    method: str = 'minmax'
    exclude: tuple[str, ...] | None = None
    holdout: tuple[tuple[float, float | None], ...] = ()
    topics: tuple[str, ...] = ()
    backend: str | None = None


@dataclass(frozen=True, slots=True)
class QuantizeOutcome:
    """What was written: the provenance stored in the model, and the warnings said once."""

    out: Path
    provenance: dict[str, Any]
    warnings: tuple[str, ...] = field(default_factory=tuple)


def parse_holdout(text: str) -> tuple[float, float | None]:
    """``START:END`` or ``START:`` (seconds of log time from the bag's start)."""
    start_text, sep, end_text = text.partition(':')
    try:
        start = float(start_text)
        end = float(end_text) if end_text.strip() else None
    except ValueError:
        start, end = -1.0, None
    if not sep or start < 0 or (end is not None and end <= start):
        msg = f'--holdout {text!r}: expected START:END or START: in seconds, START >= 0 < END'
        raise UsageError(msg)
    return start, end


# -- the model --------------------------------------------------------------------------------


def _import_onnx() -> Any:
    try:
        import onnx
    except ImportError as exc:
        from replaybench.errors import MissingDependencyError

        msg = 'quantize needs the onnx package: pip install "replaybench[quantize]"'
        raise MissingDependencyError(msg) from exc
    return onnx


def _load_model(path: Path) -> Any:
    onnx = _import_onnx()
    if not path.is_file():
        msg = f'{path}: model file not found'
        raise QuantizeError(msg)
    try:
        return onnx.load(str(path))
    except Exception as exc:  # protobuf raises DecodeError and others for a file that is no model
        msg = f'{path}: not an ONNX model ({type(exc).__name__})'
        raise QuantizeError(msg) from exc


def _opset(model: Any) -> int:
    return max(
        (int(o.version) for o in model.opset_import if o.domain in ('', 'ai.onnx')), default=0
    )


def _check_inputs(model: Any, path: Path) -> None:
    initializers = {i.name for i in model.graph.initializer}
    for inp in model.graph.input:
        if inp.name in initializers:
            continue
        dims = inp.type.tensor_type.shape.dim
        shape = [d.dim_value if d.HasField('dim_value') else (d.dim_param or '?') for d in dims]
        if not dims or not all(isinstance(v, int) and v > 0 for v in shape):
            msg = (
                f'{path}: input {inp.name!r} has no static size ({shape}); export the model '
                'with a fixed input size to quantise it'
            )
            raise QuantizeError(msg)


def _check_ops(model: Any, path: Path) -> None:
    for node in model.graph.node:
        if node.domain not in _DOMAINS:
            msg = (
                f'{path}: node {node.name or node.op_type!r} is the unsupported op '
                f'{node.domain}.{node.op_type}; quantise a model of standard ONNX ops'
            )
            raise QuantizeError(msg)


def _upgraded(model: Any, path: Path) -> tuple[Any, int, int]:
    """The model at opset >= 13: ``(model, opset_from, opset_to)``."""
    onnx = _import_onnx()
    before = _opset(model)
    if before >= MIN_OPSET:
        return model, before, before
    if before < 7:
        msg = (
            f'{path}: opset {before} is too old to upgrade to {MIN_OPSET} (per-channel '
            'quantisation needs it); re-export the model with opset 13 or newer'
        )
        raise QuantizeError(msg)
    from onnx import version_converter

    try:
        upgraded = version_converter.convert_version(model, MIN_OPSET)
        onnx.checker.check_model(upgraded)
    except Exception as exc:  # the converter raises RuntimeError / ValidationError per op
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        msg = (
            f'{path}: opset {before} cannot be upgraded to {MIN_OPSET} (per-channel '
            f'quantisation needs it): {text[:200]}'
        )
        raise QuantizeError(msg) from exc
    return upgraded, before, MIN_OPSET


def head_nodes(model: Any) -> tuple[str, ...]:
    """The decode head: each path from a graph output back to (and with) its last ``Conv``.

    Detector heads (YOLOX, YOLOv5/v8) end in 1x1 prediction convolutions followed by reshapes,
    sigmoids, the box decode and a concat of boxes (hundreds of pixels) and scores (0..1): one
    uint8 scale over that concat loses the scores, so these nodes stay in float. A model with
    no ``Conv`` has no head by this rule (nothing is excluded).
    """
    producer = {out: node for node in model.graph.node for out in node.output}
    if not any(node.op_type == 'Conv' for node in model.graph.node):
        return ()
    seen: set[int] = set()
    names: list[str] = []
    stack = [producer[o.name] for o in model.graph.output if o.name in producer]
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if node.op_type not in ('Constant', 'Shape'):
            names.append(node.name)
        if node.op_type in ('Conv', 'Shape'):  # a Shape's input is data of the trunk
            continue
        stack.extend(producer[i] for i in node.input if i in producer)
    return tuple(sorted(n for n in names if n))


def _named(model: Any) -> Any:
    """Every node with a name (``nodes_to_exclude`` names nodes): unnamed ones get
    ``<op>_<index>``."""
    used = {n.name for n in model.graph.node if n.name}
    for i, node in enumerate(model.graph.node):
        if not node.name:
            name = f'{node.op_type}_{i}'
            while name in used:
                name += '_'
            node.name = name
            used.add(name)
    return model


# -- the bag ----------------------------------------------------------------------------------


# -- the backend ------------------------------------------------------------------------------


def _task_backend(model: Any, given: str | None) -> str:
    if given is not None:
        return given
    meta = {p.key: p.value for p in model.metadata_props}
    if 'replaybench.seg_layout' in meta:
        return 'onnx-seg'
    if 'replaybench.stereo_layout' in meta:
        return 'onnx-stereo'
    return 'onnx-cpu'


def _preprocessor(backend: str, model: Path) -> Any:
    from replaybench.backends.base import BackendOptions

    options = BackendOptions(model=model, threads=1)
    if backend == 'onnx-cpu':
        from replaybench.backends.onnx_cpu import OnnxCpuBackend

        return OnnxCpuBackend(options)
    if backend == 'onnx-seg':
        from replaybench.backends.onnx_seg import OnnxSegBackend

        return OnnxSegBackend(options)
    if backend == 'onnx-stereo':
        from replaybench.backends.onnx_stereo import OnnxStereoBackend

        return OnnxStereoBackend(options)
    msg = f'quantize calibrates through onnx-cpu, onnx-seg or onnx-stereo, not {backend!r}'
    raise QuantizeError(msg)


class _Reader:
    """``CalibrationDataReader`` over prepared inputs."""

    def __init__(self, feeds: Sequence[dict[str, Any]]) -> None:
        self._feeds = list(feeds)
        self._it: Iterator[dict[str, Any]] = iter(self._feeds)

    def get_next(self) -> dict[str, Any] | None:
        return next(self._it, None)

    def rewind(self) -> None:
        self._it = iter(self._feeds)


# -- the output -------------------------------------------------------------------------------


def _check_out(out: Path, model: Path) -> None:
    if out.exists() or out.is_symlink():
        if out.is_symlink() or not out.is_file():
            msg = f'--out {out}: not a file; give the path of the .onnx model to write'
            raise QuantizeError(msg)
        if out.resolve() == model.resolve():
            msg = f'--out {out} is the input model; write the INT8 model to another file'
            raise QuantizeError(msg)
        onnx = _import_onnx()
        try:
            onnx.load(str(out), load_external_data=False)
        except Exception as exc:  # protobuf raises DecodeError and others
            msg = (
                f'--out {out} exists and is not an ONNX model (corrupt or another file): '
                'refusing to overwrite it'
            )
            raise QuantizeError(msg) from exc
    elif not out.parent.is_dir():
        try:  # as run's --out, the folders are made
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            msg = f'--out {out}: folder {out.parent} cannot be made: {err.strerror or err}'
            raise QuantizeError(msg) from None


def _sha256(path: Path) -> str:
    from replaybench.sources.digest import input_sha256

    if path.is_dir():
        return input_sha256(path)
    digest = hashlib.sha256()
    with path.open('rb') as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def quantize_model(settings: QuantizeSettings) -> QuantizeOutcome:
    """Quantise ``settings.model`` to ``settings.out`` (``QuantizeError``: one line)."""
    if settings.method not in METHODS:
        msg = f'--method {settings.method!r}: expected one of {", ".join(METHODS)}'
        raise UsageError(msg)
    if settings.frames < 1:
        msg = f'--frames must be >= 1, got {settings.frames}'
        raise UsageError(msg)
    _check_out(settings.out, settings.model)
    model = _load_model(settings.model)
    path = settings.model
    _check_inputs(model, path)
    _check_ops(model, path)
    model, opset_from, opset_to = _upgraded(model, path)
    model = _named(model)
    nodes = {n.name for n in model.graph.node}
    if settings.exclude is None:
        excluded, rule = head_nodes(model), 'decode head (last Conv of each output path on)'
    else:
        unknown = [n for n in settings.exclude if n not in nodes]
        if unknown:
            msg = f'--exclude {unknown[0]!r}: the model has no node of that name'
            raise UsageError(msg)
        excluded, rule = tuple(settings.exclude), '--exclude' if settings.exclude else 'none'
    backend = _task_backend(model, settings.backend)
    stereo = backend == 'onnx-stereo'
    if stereo:
        calib = calibration_pairs(
            settings.bag, settings.frames, settings.topics, holdout=settings.holdout
        )
    else:
        calib = calibration_frames(
            settings.bag, settings.frames, topics=settings.topics, holdout=settings.holdout
        )
    used = calib.frames[0::2] if stereo else calib.frames
    warnings: list[str] = []
    if calib.available < settings.frames:
        kind = 'stereo pair(s)' if stereo else 'frame(s)'
        warnings.append(
            f'{settings.bag.name} holds {calib.available} {kind} to calibrate on, fewer than '
            f'--frames {settings.frames}: all {calib.available} used'
        )
    pre = _preprocessor(backend, path)
    try:
        if stereo:
            from replaybench.types import FrameSet

            pairs = zip(calib.frames[0::2], calib.frames[1::2], strict=True)
            feeds = [pre.inputs(FrameSet(frames=pair)) for pair in pairs]
        else:
            feeds = [pre.inputs(frame) for frame in calib.frames]
    finally:
        pre.close()
    frames_used: dict[str, list[int]] = {}
    for frame in calib.frames:
        frames_used.setdefault(frame.topic, []).append(frame.seq)
    record: dict[str, Any] = {
        'replaybench': __version__,
        'bag': settings.bag.name,
        'bag_sha256': _sha256(settings.bag),
        'topics': list(calib.topics),
        'frames': len(used),
        'frames_asked': settings.frames,
        'frames_used': frames_used,
        'holdout': [[s, e] for s, e in settings.holdout],
        'method': settings.method,
        'format': 'QDQ',
        'per_channel': True,
        'activations': 'uint8',
        'weights': 'int8',
        'backend': backend,
        'excluded': list(excluded),
        'exclude_rule': rule,
        'opset_from': opset_from,
        'opset_to': opset_to,
        'source': path.name,
        'source_sha256': _sha256(path),
    }
    _quantize(model, feeds, settings, excluded, record)
    return QuantizeOutcome(settings.out, record, tuple(warnings))


def _quantize(
    model: Any,
    feeds: Sequence[dict[str, Any]],
    settings: QuantizeSettings,
    excluded: Sequence[str],
    record: dict[str, Any],
) -> None:
    onnx = _import_onnx()
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    method = {
        'minmax': CalibrationMethod.MinMax,
        'entropy': CalibrationMethod.Entropy,
        'percentile': CalibrationMethod.Percentile,
    }[settings.method]
    out = settings.out
    with tempfile.TemporaryDirectory(prefix='replaybench-quantize-') as tmp:
        work = Path(tmp)
        source = work / 'float.onnx'
        onnx.save(model, str(source))
        target = work / 'int8.onnx'
        import logging

        root = logging.getLogger()
        level = root.level
        root.setLevel(logging.ERROR)  # its advice to pre-process goes to the root logger
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # its calibrators print progress
                quantize_static(
                    str(source),
                    str(target),
                    _Reader(feeds),
                    quant_format=QuantFormat.QDQ,
                    per_channel=True,
                    activation_type=QuantType.QUInt8,
                    weight_type=QuantType.QInt8,
                    nodes_to_exclude=list(excluded),
                    calibrate_method=method,
                )
        except Exception as exc:  # onnxruntime raises several types for ops it cannot take
            text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            msg = f'{settings.model}: ONNX Runtime cannot quantise it: {text[:200]}'
            raise QuantizeError(msg) from exc
        finally:
            root.setLevel(level)
        result = onnx.load(str(target))
        kept = [p for p in result.metadata_props if p.key != PROVENANCE_KEY]
        del result.metadata_props[:]
        result.metadata_props.extend(kept)
        entry = result.metadata_props.add()
        entry.key = PROVENANCE_KEY
        entry.value = json.dumps(record, sort_keys=True, separators=(',', ':'))
        staged = work / 'out.onnx'
        onnx.save(result, str(staged))
        partial = out.with_name(f'.{out.name}.partial')
        try:
            shutil.copyfile(staged, partial)
            partial.replace(out)
        except OSError as exc:
            partial.unlink(missing_ok=True)
            from replaybench.errors import OutputError

            msg = f'cannot write {out}: {exc.strerror or exc}'
            raise OutputError(msg) from exc
