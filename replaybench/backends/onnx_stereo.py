"""ONNX Runtime stereo on the CPU: a network's disparity of each synchronised left/right pair.

A backend that takes frame sets (``--sync``), of the ``stereo`` task: each set is a left and a
right image, in that order. As ``sgbm``, the pair's geometry comes from the two frames'
CameraInfo (``replaybench.stereo.stereo_pair``) and raw pairs are rectified with maps built
once per pair of topics (``Rectifier``).

The model's layout (``--model-family``, else the ``replaybench.stereo_layout`` metadata, else
the input shapes):

- ``two-inputs``: two inputs ``[1, C, H, W]`` (C 1 grey or 3 colour), the left one named
  ``left`` (or the first), the right one ``right`` (or the second);
- ``six-channel``: one input ``[1, 2C, H, W]``, the left image's channels then the right's
  (C 3: a 6-channel input; C 1: 2 channels).

The output (one, or the one named ``disparity``): ``[1, 1, h, w]``, ``[1, h, w]`` or ``[h, w]``
disparity of the left image in the network's pixels; it is resized bilinearly to the image
and its values multiplied by the width's ratio (image width / network width). Values that are
not finite are no estimate. Input sizes must be fixed in the model.

Stages per pair (``StageTimes``): ``preprocess_ns`` = rectification, channel conversion,
resize to the network's size and scale into the preallocated input tensors; ``infer_ns`` =
``InferenceSession.run``; ``postprocess_ns`` = the resize back and the ``Disparity``.

Options: ``model`` (default: the bundled ``stereo_small.onnx``, trained on generated pairs,
docs/stereo.md), ``model_family`` (``two-inputs`` or ``six-channel``), ``threads``
(intra-op threads). ``extra``: ``channel_order`` (``grey``, ``rgb`` or ``bgr``; default from
the ``replaybench.channel_order`` metadata, else grey for 1 channel and rgb for 3), ``scale``
(the factor from 0..255 pixels to the input's values; default the ``replaybench.scale``
metadata, else 1/255), ``max_disparity`` (the network's largest disparity in its own pixels,
written in the DisparityImage; default the ``replaybench.max_disparity`` metadata, else the
network's width / 4) and ``allow_spinning``.
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from replaybench.backends.base import Availability, BackendOptions
from replaybench.backends.onnx_cpu import onnx_cpu_available, session_options
from replaybench.backends.sgbm import StereoPairs
from replaybench.errors import BackendError, BackendUnavailableError, StereoError
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    import numpy.typing as npt

    from replaybench.types import FrameSet

__all__ = ['DEFAULT_STEREO_MODEL', 'EXTRA_KEYS', 'LAYOUTS', 'OnnxStereoBackend', 'StereoModelSpec']

#: The bundled model (training/train_stereo.py).
DEFAULT_STEREO_MODEL = Path(__file__).resolve().parents[1] / 'models' / 'stereo_small.onnx'
#: The input layouts a model may have.
LAYOUTS = ('two-inputs', 'six-channel')
#: Keys ``BackendOptions.extra`` may hold for this backend.
EXTRA_KEYS = ('channel_order', 'scale', 'max_disparity', 'allow_spinning', 'rectify_maps')
_ORDERS = ('grey', 'rgb', 'bgr')


@dataclass(frozen=True, slots=True)
class StereoModelSpec:
    """What the backend read of a stereo model: its layout, inputs, output and preprocessing."""

    layout: str
    layout_source: str
    input_names: tuple[str, ...]
    input_shapes: tuple[tuple[int, ...], ...]
    channels: int  # per image
    size: tuple[int, int]  # the network's width, height
    output_name: str
    output_shape: tuple[Any, ...]
    channel_order: str
    scale: float
    max_disparity: float
    sha256: str


def _fixed_shape(name: str, shape: list[Any], path: Path) -> tuple[int, ...]:
    if len(shape) != 4 or not all(isinstance(v, int) and v > 0 for v in shape) or shape[0] != 1:
        msg = (
            f'{path}: input {name!r} has shape {shape}; a stereo model takes fixed '
            '[1, C, H, W] inputs'
        )
        raise BackendError(msg)
    return tuple(int(v) for v in shape)


def _layout(
    inputs: list[Any], family: str | None, meta: dict[str, str], path: Path
) -> tuple[str, str]:
    if family is not None:
        return family, '--model-family'
    named = meta.get('replaybench.stereo_layout')
    if named is not None:
        if named not in LAYOUTS:
            msg = (
                f'{path}: metadata replaybench.stereo_layout={named!r} is no layout '
                f'(known: {", ".join(LAYOUTS)})'
            )
            raise BackendError(msg)
        return named, 'metadata'
    if len(inputs) == 2:
        return 'two-inputs', 'input shapes'
    if len(inputs) == 1:
        return 'six-channel', 'input shapes'
    msg = f'{path}: a stereo model has one or two inputs, this one has {len(inputs)}'
    raise BackendError(msg)


def _inputs(
    session: Any, layout: str, path: Path
) -> tuple[tuple[str, ...], tuple[tuple[int, ...], ...], int]:
    inputs = session.get_inputs()
    for inp in inputs:
        if inp.type != 'tensor(float)':
            msg = f'{path}: input {inp.name!r} is {inp.type}; a stereo model takes float32'
            raise BackendError(msg)
    if layout == 'two-inputs':
        if len(inputs) != 2:
            msg = f'{path}: layout two-inputs needs two inputs, the model has {len(inputs)}'
            raise BackendError(msg)
        names = [i.name for i in inputs]
        lowered = [n.lower() for n in names]
        if 'left' in lowered[1] and 'right' in lowered[0]:
            inputs = inputs[::-1]
        shapes = tuple(_fixed_shape(i.name, list(i.shape), path) for i in inputs)
        if shapes[0] != shapes[1] or shapes[0][1] not in (1, 3):
            msg = (
                f'{path}: the two inputs have shapes {list(shapes[0])} and {list(shapes[1])}; '
                'they must be the same [1, C, H, W] with C 1 or 3'
            )
            raise BackendError(msg)
        return tuple(i.name for i in inputs), shapes, shapes[0][1]
    if len(inputs) != 1:
        msg = f'{path}: layout six-channel needs one input, the model has {len(inputs)}'
        raise BackendError(msg)
    shape = _fixed_shape(inputs[0].name, list(inputs[0].shape), path)
    if shape[1] not in (2, 6):
        msg = (
            f'{path}: input {inputs[0].name!r} has {shape[1]} channels; layout six-channel '
            'takes 6 (two colour images) or 2 (two grey ones)'
        )
        raise BackendError(msg)
    return (inputs[0].name,), (shape,), shape[1] // 2


def _output(session: Any, path: Path) -> tuple[str, tuple[Any, ...]]:
    outputs = session.get_outputs()
    named = [o for o in outputs if o.name == 'disparity']
    if len(outputs) != 1 and not named:
        msg = (
            f'{path}: a stereo model has one output (or one named disparity), this one has '
            f'{len(outputs)}'
        )
        raise BackendError(msg)
    out = named[0] if named else outputs[0]
    shape = tuple(out.shape)
    if len(shape) not in (2, 3, 4) or any(v != 1 for v in shape[:-2] if isinstance(v, int)):
        msg = (
            f'{path}: output {out.name!r} has shape {list(shape)}; a stereo model gives '
            '[1, 1, H, W], [1, H, W] or [H, W] disparity'
        )
        raise BackendError(msg)
    return str(out.name), shape


def _float(key: str, text: str, source: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float('nan')
    if not (np.isfinite(value) and value > 0):
        msg = f'{source} {key}={text!r} is not a positive number'
        raise BackendError(msg)
    return value


def load_stereo_spec(
    path: Path, session: Any, family: str | None, extra: dict[str, str]
) -> StereoModelSpec:
    """The spec of a loaded model (``BackendError``, one line, for a model that is no stereo
    model of a known layout)."""
    meta = dict(session.get_modelmeta().custom_metadata_map)
    layout, source = _layout(session.get_inputs(), family, meta, path)
    names, shapes, channels = _inputs(session, layout, path)
    size = (shapes[0][3], shapes[0][2])
    output_name, output_shape = _output(session, path)
    order = extra.get('channel_order') or meta.get('replaybench.channel_order')
    if order is None:
        order = 'grey' if channels == 1 else 'rgb'
    if order not in _ORDERS:
        msg = f'{path}: channel order {order!r} is not one of {", ".join(_ORDERS)}'
        raise BackendError(msg)
    if (order == 'grey') != (channels == 1):
        msg = f'{path}: channel order {order} does not fit {channels}-channel images'
        raise BackendError(msg)
    scale = _float(
        'scale', extra.get('scale') or meta.get('replaybench.scale', repr(1 / 255)), 'option'
    )
    max_d = _float(
        'max_disparity',
        extra.get('max_disparity') or meta.get('replaybench.max_disparity', str(size[0] / 4)),
        'option',
    )
    return StereoModelSpec(
        layout=layout,
        layout_source=source,
        input_names=names,
        input_shapes=shapes,
        channels=channels,
        size=size,
        output_name=output_name,
        output_shape=output_shape,
        channel_order=order,
        scale=scale,
        max_disparity=max_d,
        sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
    )


class OnnxStereoBackend(StereoPairs):
    """ONNX Runtime ``InferenceSession`` (``CPUExecutionProvider``) of a stereo model.

    Session options as ``onnx-cpu``'s (``session_options``). Returns a
    ``replaybench.stereo.Disparity`` in ``BackendResult.output`` and no detections.
    """

    name: ClassVar[str] = 'onnx-stereo'
    description: ClassVar[str] = (
        'ONNX Runtime CPU stereo network: left/right or 6-channel input (--model, --sync)'
    )
    providers: ClassVar[tuple[str, ...]] = ('CPUExecutionProvider',)
    task: ClassVar[str] = 'stereo'

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        opts = self.options
        if opts.model_family is not None and opts.model_family not in LAYOUTS:
            msg = (
                f'{self.name}: --model-family {opts.model_family!r} is no stereo layout '
                f'(known: {", ".join(LAYOUTS)})'
            )
            raise BackendError(msg)
        if opts.threads is not None and opts.threads < 1:
            msg = f'{self.name}: --threads must be >= 1, got {opts.threads}'
            raise BackendError(msg)
        unknown = sorted(set(opts.extra) - set(EXTRA_KEYS))
        if unknown:
            msg = f'{self.name}: unknown option {unknown[0]!r} (known: {", ".join(EXTRA_KEYS)})'
            raise BackendError(msg)
        spinning = opts.extra.get('allow_spinning', '0').strip().lower()
        if spinning not in ('0', '1', 'true', 'false'):
            msg = (
                f'{self.name}: allow_spinning must be 0 or 1, got {opts.extra["allow_spinning"]!r}'
            )
            raise BackendError(msg)
        self.spinning = spinning in ('1', 'true')
        self.take_pairs(opts.extra.get('rectify_maps'))
        self.model_path: Path = opts.model if opts.model is not None else DEFAULT_STEREO_MODEL
        self.spec: StereoModelSpec | None = None
        self._session: Any = None
        self._buffers: tuple[npt.NDArray[np.float32], ...] = ()
        self._feed: dict[str, Any] = {}
        self._ort_version = ''
        self._providers_used: list[str] = []
        self._intra_threads = 0

    @classmethod
    def available(cls) -> Availability:
        return onnx_cpu_available()

    def open(self) -> None:
        if self._session is not None:
            return
        try:
            import onnxruntime as ort
        except ImportError as exc:
            msg = f'{self.name}: cannot import onnxruntime: {exc}'
            raise BackendUnavailableError(msg) from exc
        path = self.model_path
        if not path.is_file():
            msg = f'{self.name}: model file {path} not found'
            raise BackendError(msg)
        so = session_options(self.options.threads, spinning=self.spinning)
        try:
            session = ort.InferenceSession(str(path), so, providers=list(self.providers))
        except Exception as exc:  # onnxruntime raises several types for bad models
            text = str(exc).splitlines()[0] if str(exc) else ''
            msg = f'{self.name}: cannot load {path}: {type(exc).__name__}: {text}'
            raise BackendError(msg) from exc
        extra = {
            k: v
            for k, v in self.options.extra.items()
            if k not in ('allow_spinning', 'rectify_maps')
        }
        try:
            spec = load_stereo_spec(path, session, self.options.model_family, extra)
        except BackendError as exc:
            msg = f'{self.name}: {exc}'
            raise BackendError(msg) from exc
        buffers = tuple(np.zeros(shape, dtype=np.float32) for shape in spec.input_shapes)
        self.spec = spec
        self._buffers = buffers
        self._feed = dict(zip(spec.input_names, buffers, strict=True))
        self._ort_version = str(ort.__version__)
        self._providers_used = list(session.get_providers())
        self._intra_threads = int(so.intra_op_num_threads)
        self._session = session

    def close(self) -> None:
        self._session = None
        self._buffers = ()
        self._feed = {}
        self._rectifiers.clear()

    def _channels(self, image: npt.NDArray[Any], encoding: str) -> npt.NDArray[np.uint8]:
        """An image as the network's channels (HxW grey, or HxWx3 in its order), uint8."""
        from replaybench.decode import to_bgr8
        from replaybench.stereo import to_mono8

        spec = self.spec
        assert spec is not None
        if spec.channel_order == 'grey':
            return to_mono8(image, encoding)
        bgr = to_bgr8(image, encoding)
        return bgr[:, :, ::-1] if spec.channel_order == 'rgb' else bgr

    def _fill(self, images: tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]]) -> None:
        import cv2

        spec = self.spec
        assert spec is not None
        width, height = spec.size
        scale = np.float32(spec.scale)
        c = spec.channels
        for i, image in enumerate(images):
            if image.shape[1] != width or image.shape[0] != height:
                resized = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
                image = np.asarray(resized, dtype=np.uint8)
            planes = image[None] if image.ndim == 2 else image.transpose(2, 0, 1)
            target = (
                self._buffers[i][0]
                if len(self._buffers) == 2
                else self._buffers[0][0, i * c : (i + 1) * c]
            )
            np.multiply(planes, scale, out=target, casting='unsafe')

    def detect(self, frame_set: FrameSet) -> BackendResult:
        import cv2

        from replaybench.stereo import Disparity

        if self._session is None:
            self.open()
        spec = self.spec
        assert spec is not None
        if len(frame_set.frames) != 2:
            msg = (
                f'{self.name} takes a left and a right image, not {len(frame_set.frames)} '
                f'({", ".join(frame_set.topics)}): give --stereo LEFT,RIGHT'
            )
            raise StereoError(msg)
        left, right = frame_set.frames
        clock = time.perf_counter_ns
        t0 = clock()
        for frame in (left, right):
            if frame.is_depth or frame.encoding == '32FC1':
                msg = (
                    f'{self.name}: frame {frame.topic}#{frame.seq} is a depth image '
                    f'({frame.source_encoding}); replay colour or mono topics only'
                )
                raise BackendError(msg)
        rectifier = self.rectifier(left, right)
        rect_left, rect_right = rectifier.rectify(left.image, right.image)
        self._fill(
            (self._channels(rect_left, left.encoding), self._channels(rect_right, right.encoding))
        )
        t1 = clock()
        try:
            (output,) = self._session.run([spec.output_name], self._feed)
        except Exception as exc:  # onnxruntime errors have several types
            text = str(exc).splitlines()[0] if str(exc) else ''
            msg = f'{self.name}: inference failed: {type(exc).__name__}: {text}'
            raise BackendError(msg) from exc
        t2 = clock()
        values = np.asarray(output, dtype=np.float32)
        net: npt.NDArray[np.float32] = values.reshape(values.shape[-2:])
        width, height = rectifier.pair.size
        ratio = width / net.shape[1]
        if net.shape[0] != height or net.shape[1] != width:
            net = np.asarray(
                cv2.resize(net, (width, height), interpolation=cv2.INTER_LINEAR), dtype=np.float32
            )
        disparity = np.multiply(net, np.float32(ratio), dtype=np.float32) if ratio != 1 else net
        result = Disparity.of_pair(
            disparity,
            rectifier.pair,
            min_disparity=0.0,
            max_disparity=spec.max_disparity * ratio,
            delta_d=0.0,
            valid_window=(0, 0, height, width),
        )
        t3 = clock()
        return BackendResult(
            (),
            StageTimes(preprocess_ns=t1 - t0, infer_ns=t2 - t1, postprocess_ns=t3 - t2),
            output=result,
        )

    def inputs(self, frame_set: FrameSet) -> dict[str, Any]:
        """The model's inputs for a left/right set as ``detect`` prepares them (rectified,
        converted, resized and scaled; a copy): what ``replaybench quantize`` calibrates on."""
        if self._session is None:
            self.open()
        left, right = frame_set.frames
        rectifier = self.rectifier(left, right)
        rect_left, rect_right = rectifier.rectify(left.image, right.image)
        self._fill(
            (self._channels(rect_left, left.encoding), self._channels(rect_right, right.encoding))
        )
        return {name: buffer.copy() for name, buffer in self._feed.items()}

    def info(self) -> dict[str, Any]:
        facts: dict[str, Any] = {
            'task': 'stereo',
            'model': str(self.model_path),
            'threads': self.options.threads,
        }
        spec = self.spec
        if spec is None or self._session is None:
            return facts
        facts.update(
            {
                'model_sha256': spec.sha256,
                'layout': spec.layout,
                'layout_source': spec.layout_source,
                'inputs': [
                    {'name': n, 'shape': list(s)}
                    for n, s in zip(spec.input_names, spec.input_shapes, strict=True)
                ],
                'input_size': list(spec.size),
                'output': {'name': spec.output_name, 'shape': list(spec.output_shape)},
                'channel_order': spec.channel_order,
                'scale': spec.scale,
                'max_disparity': spec.max_disparity,
                'resize': 'area to the network, bilinear back, values x width ratio',
                'rectified': self.rectified(),
                'rectify_maps': self.rectify_maps,
                'engine': 'onnxruntime',
                'onnxruntime': self._ort_version,
                'providers': list(self._providers_used),
                'intra_op_threads': self._intra_threads,
                'intra_op_spinning': self.spinning,
                'cpu_count': os.cpu_count(),
            }
        )
        return facts
