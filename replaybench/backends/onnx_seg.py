"""ONNX Runtime segmentation on the CPU: class scores or class ids -> a label mask per frame.

Stages per frame (``StageTimes``): ``preprocess_ns`` = stretch or letterbox, channel order and
scale into the preallocated input tensor (``replaybench.detector.preprocess.Letterboxer``, as
for detectors); ``infer_ns`` = ``InferenceSession.run``; ``postprocess_ns`` = argmax (or the
class ids as they are) and the nearest-neighbour map back to the frame
(``replaybench.segmentation.decoder``). Decoding the image is the engine's ``read_decode``.

Options: ``model`` (default: the bundled ``blobs_seg.onnx``, trained on the fixture scenes),
``model_family`` (the output layout: ``logits-nchw``, ``logits-nhwc`` or ``labels``; default
from the ``replaybench.seg_layout`` metadata, else the output's shape), ``labels`` (class
names), ``threads`` (intra-op threads). ``extra`` may hold the preprocessing overrides of the
detectors (``letterbox``, ``channel_order``, ``scale``, ``mean``, ``std``, ``pad_value``,
``letterbox_align``), ``size`` (``W`` or ``WxH`` for dynamic inputs) and ``allow_spinning``.
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.backends.onnx_cpu import onnx_cpu_available, session_options
from replaybench.detector.provenance import provenance
from replaybench.detector.spec import SPEC_KEYS
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.segmentation.decoder import LAYOUTS, decode_labels, parse_layout
from replaybench.segmentation.spec import DEFAULT_SEG_MODEL
from replaybench.types import BackendResult, LabelMask, StageTimes

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.detector.preprocess import Letterboxer
    from replaybench.segmentation.decoder import SourceMapper
    from replaybench.segmentation.spec import SegModelSpec
    from replaybench.types import Frame

__all__ = ['EXTRA_KEYS', 'OnnxSegBackend']

#: Keys ``BackendOptions.extra`` may hold for this backend.
EXTRA_KEYS = (*SPEC_KEYS, 'allow_spinning')


class OnnxSegBackend:
    """ONNX Runtime ``InferenceSession`` (``CPUExecutionProvider``) of a segmentation model.

    Session options as ``onnx-cpu``'s (``session_options``). Returns ``BackendResult.mask``
    (frame-sized uint8 class ids) and no detections.
    """

    #: ``detect`` never reads ``frame.camera_info``.
    reads_camera_info: ClassVar[bool] = False

    name: ClassVar[str] = 'onnx-seg'
    description: ClassVar[str] = (
        'ONNX Runtime CPU segmentation: [1,C,H,W] / [1,H,W,C] scores or class-id outputs (--model)'
    )
    providers: ClassVar[tuple[str, ...]] = ('CPUExecutionProvider',)
    #: Its results carry a label mask (``Backend.task``).
    task: ClassVar[str] = 'segmentation'

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        opts = self.options
        self.layout = None
        if opts.model_family is not None:
            try:
                self.layout = parse_layout(opts.model_family, f'{self.name}: --model-family')
            except BackendError as exc:
                msg = f'{exc} (known: {", ".join(LAYOUTS)})'
                raise BackendError(msg) from exc
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
        self.model_path: Path = opts.model if opts.model is not None else DEFAULT_SEG_MODEL
        self.spec: SegModelSpec | None = None
        self._session: Any = None
        self._letterbox: Letterboxer | None = None
        self._mapper: SourceMapper | None = None
        self._names: list[str] = []
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
        from replaybench.detector.preprocess import Letterboxer
        from replaybench.segmentation.decoder import SourceMapper
        from replaybench.segmentation.spec import load_seg_spec

        path = self.model_path
        if not path.is_file():
            msg = f'{self.name}: model file {path} not found'
            raise BackendError(msg)
        so = session_options(self.options.threads, spinning=self.spinning)
        try:
            session = ort.InferenceSession(str(path), so, providers=list(self.providers))
        except Exception as exc:  # onnxruntime raises several types for bad models
            msg = f'{self.name}: cannot load {path}: {type(exc).__name__}: {exc}'
            raise BackendError(msg) from exc
        try:
            spec = load_seg_spec(
                path,
                session,
                layout=self.layout,
                labels=self.options.labels,
                overrides={k: v for k, v in self.options.extra.items() if k != 'allow_spinning'},
            )
        except BackendError as exc:
            msg = f'{self.name}: {exc}'
            raise BackendError(msg) from exc
        letterbox = Letterboxer(spec.preprocess, spec.precision)
        self.spec = spec
        self._letterbox = letterbox
        self._mapper = SourceMapper(spec.preprocess.size)
        self._names = [spec.output_name]
        self._feed = {spec.input_name: letterbox.output}
        self._ort_version = str(ort.__version__)
        self._providers_used = list(session.get_providers())
        self._intra_threads = int(so.intra_op_num_threads)
        self._session = session

    def close(self) -> None:
        self._session = None
        self._letterbox = None
        self._mapper = None
        self._feed = {}

    def detect(self, frame: Frame) -> BackendResult:
        if self._session is None:
            self.open()
        letterbox, mapper, spec = self._letterbox, self._mapper, self.spec
        assert letterbox is not None
        assert mapper is not None
        assert spec is not None
        clock = time.perf_counter_ns

        t0 = clock()
        if frame.is_depth or frame.encoding == '32FC1':
            msg = (
                f'{self.name}: frame {frame.topic}#{frame.seq} is a depth image '
                f'({frame.source_encoding}); replay colour or mono topics only'
            )
            raise BackendError(msg)
        try:
            _, transform = letterbox(frame.image, frame.encoding)
        except BackendError as exc:
            msg = f'{self.name}: frame {frame.topic}#{frame.seq}: {exc}'
            raise BackendError(msg) from exc
        t1 = clock()
        try:
            (output,) = self._session.run(self._names, self._feed)
        except Exception as exc:  # onnxruntime errors have several types
            msg = f'{self.name}: inference failed: {type(exc).__name__}: {exc}'
            raise BackendError(msg) from exc
        t2 = clock()
        try:
            labels = mapper(decode_labels(output, spec.layout.layout), transform)
        except BackendError as exc:
            msg = f'{self.name}: frame {frame.topic}#{frame.seq}: {exc}'
            raise BackendError(msg) from exc
        t3 = clock()
        return BackendResult(
            (),
            StageTimes(preprocess_ns=t1 - t0, infer_ns=t2 - t1, postprocess_ns=t3 - t2),
            LabelMask(labels, spec.class_names),
        )

    def inputs(self, frame: Frame) -> dict[str, Any]:
        """The model's inputs for ``frame`` as ``detect`` prepares them (a copy): what
        ``replaybench quantize`` calibrates on."""
        if self._session is None:
            self.open()
        letterbox, spec = self._letterbox, self.spec
        assert letterbox is not None
        assert spec is not None
        if frame.is_depth or frame.encoding == '32FC1':
            msg = (
                f'{self.name}: frame {frame.topic}#{frame.seq} is a depth image '
                f'({frame.source_encoding}); replay colour or mono topics only'
            )
            raise BackendError(msg)
        tensor, _ = letterbox(frame.image, frame.encoding)
        return {spec.input_name: tensor.copy()}

    def info(self) -> dict[str, Any]:
        facts: dict[str, Any] = {
            'task': 'segmentation',
            'model': str(self.model_path),
            'threads': self.options.threads,
        }
        spec = self.spec
        if spec is None or self._session is None:
            return facts
        pre = spec.preprocess
        facts.update(
            {
                'model_sha256': spec.sha256,
                'layout': spec.layout.layout,
                'layout_source': spec.layout_source,
                'input': {'name': spec.input_name, 'shape': list(spec.input_shape)},
                'input_size': [pre.size[0], pre.size[1]],
                'output': {'name': spec.output_name, 'shape': list(spec.output_shape)},
                'precision': spec.precision,
                'class_names': list(spec.class_names),
                'labels_source': spec.labels_source,
                'quantization': provenance(spec.metadata),
                'preprocess': {
                    'letterbox': pre.letterbox,
                    'align': pre.align,
                    'pad_value': pre.pad_value,
                    'channel_order': pre.channel_order,
                    'scale': pre.scale,
                    'mean': list(pre.mean),
                    'std': list(pre.std),
                },
                'postprocess': 'argmax over classes'
                if spec.layout.layout != 'labels'
                else 'class ids as output',
                'resize': 'nearest, by source pixel centre',
                'engine': 'onnxruntime',
                'onnxruntime': self._ort_version,
                'providers': list(self._providers_used),
                'intra_op_threads': self._intra_threads,
                'intra_op_spinning': self.spinning,
                'cpu_count': os.cpu_count(),
            }
        )
        return facts
