"""ONNX Runtime detector on the CPU: YOLOX, YOLOv5/v7, YOLOv8/YOLO11 and NMS-in-graph models.

Stages per frame (``StageTimes``): ``preprocess_ns`` = letterbox/resize, channel order, scale
into the preallocated input tensor (``replaybench.detector.preprocess``); ``infer_ns`` =
``InferenceSession.run``; ``postprocess_ns`` = decode, NMS, mapping to source pixels and
building the Detections (``replaybench.detector.decoders``).

Options: ``model`` (default: the bundled ``DEFAULT_MODEL``), ``model_family``, ``labels``,
``conf``, ``iou``, ``threads`` (ONNX Runtime intra-op threads). ``extra`` may hold
preprocessing overrides (``channel_order``, ``scale``, ``pad_value``, ``letterbox_align``,
``letterbox``, ``mean``, ``std``), ``size`` (``W`` or ``WxH`` for dynamic inputs),
``max_det`` and ``allow_spinning`` (``1``: let idle intra-op threads spin; default ``0``).

Candidates whose model outputs are NaN or inf are left out; ``info()`` counts them
(``nonfinite_dropped`` candidates in ``nonfinite_frames`` frames).
"""

from __future__ import annotations

import importlib.util
import os
import time
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.base import Availability, BackendOptions
from replaybench.detector.decoders import NonfiniteTally
from replaybench.detector.provenance import provenance
from replaybench.detector.spec import DEFAULT_CONF, DEFAULT_IOU, DEFAULT_MODEL, FAMILIES, SPEC_KEYS
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from replaybench.detector.preprocess import Letterboxer
    from replaybench.detector.spec import ModelSpec
    from replaybench.types import Detection, Frame

__all__ = ['EXTRA_KEYS', 'OnnxCpuBackend', 'onnx_cpu_available', 'session_options']

#: Keys ``BackendOptions.extra`` may hold for this backend.
EXTRA_KEYS = (*SPEC_KEYS, 'max_det', 'allow_spinning')
_META_VALUE_CHARS = 200


def onnx_cpu_available() -> Availability:
    """Whether the ONNX Runtime CPU backends (``onnx-cpu``, ``onnx-seg``) can run here."""
    if importlib.util.find_spec('onnxruntime') is None:
        return Availability(ok=False, reason='onnxruntime is not installed')
    if importlib.util.find_spec('cv2') is None:
        return Availability(ok=False, reason='OpenCV (cv2) is not installed')
    return Availability(ok=True)


def session_options(threads: int | None, *, spinning: bool = False) -> Any:
    """The ``onnxruntime.SessionOptions`` of ``onnx-cpu``.

    ``threads`` intra-op threads (None: onnxruntime's default), one inter-op thread,
    sequential execution, all graph optimisations. Spinning of idle intra-op threads is off
    unless ``spinning``: a spinning pool takes CPU from the replay between frames and from
    every other process; a 30 ms inference does not notice the wake-up.
    """
    import onnxruntime as ort

    so = ort.SessionOptions()
    if threads is not None:
        so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    so.add_session_config_entry('session.intra_op.allow_spinning', '1' if spinning else '0')
    return so


def _not_open(*_args: object) -> tuple[Detection, ...]:
    msg = 'onnx-cpu: the backend is not open'
    raise BackendError(msg)


def _check_unit(name: str, value: float | None) -> None:
    if value is not None and not 0.0 <= value <= 1.0:
        msg = f'onnx-cpu: --{name} must be within 0..1, got {value}'
        raise BackendError(msg)


class OnnxCpuBackend:
    """ONNX Runtime ``InferenceSession`` with ``CPUExecutionProvider`` only.

    Session: ``session_options(options.threads)``: intra-op threads = ``options.threads``
    when given (else ONNX Runtime's default), one inter-op thread, sequential execution, all
    graph optimisations, no spinning of idle threads (``extra['allow_spinning']='1'`` turns
    it on).
    """

    #: ``detect`` never reads ``frame.camera_info``.
    reads_camera_info: ClassVar[bool] = False

    name: ClassVar[str] = 'onnx-cpu'
    description: ClassVar[str] = (
        'ONNX Runtime CPU: YOLOX / YOLOv5 / YOLOv8 / NMS-in-graph detectors (--model)'
    )
    #: Execution providers asked for; subclasses for other devices replace them.
    providers: ClassVar[tuple[str, ...]] = ('CPUExecutionProvider',)

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        opts = self.options
        _check_unit('conf', opts.conf)
        _check_unit('iou', opts.iou)
        if opts.model_family is not None and opts.model_family not in FAMILIES:
            known = ', '.join(FAMILIES)
            msg = f'onnx-cpu: unknown --model-family {opts.model_family!r}; known: {known}'
            raise BackendError(msg)
        if opts.threads is not None and opts.threads < 1:
            msg = f'onnx-cpu: --threads must be >= 1, got {opts.threads}'
            raise BackendError(msg)
        unknown = sorted(set(opts.extra) - set(EXTRA_KEYS))
        if unknown:
            msg = f'onnx-cpu: unknown option {unknown[0]!r} (known: {", ".join(EXTRA_KEYS)})'
            raise BackendError(msg)
        self.max_det = 300
        if 'max_det' in opts.extra:
            try:
                self.max_det = int(opts.extra['max_det'])
            except ValueError:
                self.max_det = 0
            if self.max_det < 1:
                msg = f'onnx-cpu: max_det must be an integer >= 1, got {opts.extra["max_det"]!r}'
                raise BackendError(msg)
        spinning = opts.extra.get('allow_spinning', '0').strip().lower()
        if spinning not in ('0', '1', 'true', 'false'):
            msg = f'onnx-cpu: allow_spinning must be 0 or 1, got {opts.extra["allow_spinning"]!r}'
            raise BackendError(msg)
        self.spinning = spinning in ('1', 'true')
        self.model_path: Path = opts.model if opts.model is not None else DEFAULT_MODEL
        self.spec: ModelSpec | None = None
        self.conf = opts.conf
        self.iou = opts.iou if opts.iou is not None else DEFAULT_IOU
        self._session: Any = None
        self._ort_version = ''
        self._providers_used: list[str] = []
        self._intra_threads = 0
        self._letterbox: Letterboxer | None = None
        self._postprocess: Callable[..., tuple[Detection, ...]] = _not_open
        self._names: list[str] = []
        self._feed: dict[str, Any] = {}
        self.nonfinite = NonfiniteTally()

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
        from replaybench.detector.decoders import postprocess
        from replaybench.detector.preprocess import Letterboxer
        from replaybench.detector.spec import load_model_spec

        path = self.model_path
        if not path.is_file():
            if self.options.model is None:
                msg = (
                    f'{self.name}: no --model given and the bundled model {path.name} is not '
                    f'installed ({path}); pass --model PATH.onnx'
                )
            else:
                msg = f'{self.name}: model file {path} not found'
            raise BackendError(msg)
        so = session_options(self.options.threads, spinning=self.spinning)
        try:
            session = ort.InferenceSession(str(path), so, providers=list(self.providers))
        except Exception as exc:  # onnxruntime raises several types for bad models
            msg = f'{self.name}: cannot load {path}: {type(exc).__name__}: {exc}'
            raise BackendError(msg) from exc
        used = list(session.get_providers())
        missing = [p for p in self.providers if p not in used]
        if missing:
            msg = (
                f'{self.name}: onnxruntime did not enable {", ".join(missing)} '
                f'(in use: {", ".join(used) or "none"}; this build offers '
                f'{", ".join(ort.get_available_providers())})'
            )
            raise BackendUnavailableError(msg)
        try:
            spec = load_model_spec(
                path,
                family=self.options.model_family,
                labels=self.options.labels,
                session=session,
                overrides={
                    k: v
                    for k, v in self.options.extra.items()
                    if k not in ('max_det', 'allow_spinning')
                },
            )
        except BackendError as exc:
            msg = f'{self.name}: {exc}'
            raise BackendError(msg) from exc
        letterbox = Letterboxer(spec.preprocess, spec.precision)
        self.spec = spec
        self.conf = (
            self.options.conf if self.options.conf is not None else DEFAULT_CONF[spec.family]
        )
        self._letterbox = letterbox
        self._postprocess = postprocess
        self._names = list(spec.output_names)
        self._feed = {spec.input_name: letterbox.output}
        self._ort_version = str(ort.__version__)
        self._providers_used = used
        self._intra_threads = int(so.intra_op_num_threads)
        self._session = session

    def close(self) -> None:
        self._session = None
        self._letterbox = None
        self._feed = {}

    def _refuse(self, frame: Frame) -> BackendError:
        msg = (
            f'{self.name}: frame {frame.topic}#{frame.seq} is a depth image '
            f'({frame.source_encoding}); a detector for colour images cannot use it: '
            'replay colour or mono topics only'
        )
        return BackendError(msg)

    def detect(self, frame: Frame) -> BackendResult:
        if self._session is None:
            self.open()
        letterbox = self._letterbox
        spec = self.spec
        assert letterbox is not None
        assert spec is not None
        clock = time.perf_counter_ns

        t0 = clock()
        if frame.is_depth or frame.encoding == '32FC1':
            raise self._refuse(frame)
        try:
            _, transform = letterbox(frame.image, frame.encoding)
        except BackendError as exc:
            msg = f'{self.name}: frame {frame.topic}#{frame.seq}: {exc}'
            raise BackendError(msg) from exc
        t1 = clock()
        try:
            outputs = self._session.run(self._names, self._feed)
        except Exception as exc:  # onnxruntime errors have several types
            msg = f'{self.name}: inference failed: {type(exc).__name__}: {exc}'
            raise BackendError(msg) from exc
        t2 = clock()
        detections = self._postprocess(
            dict(zip(self._names, outputs, strict=True)),
            spec,
            transform,
            self.conf if self.conf is not None else DEFAULT_CONF[spec.family],
            self.iou,
            self.max_det,
            self.nonfinite,
        )
        t3 = clock()
        return BackendResult(
            detections, StageTimes(preprocess_ns=t1 - t0, infer_ns=t2 - t1, postprocess_ns=t3 - t2)
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
            raise self._refuse(frame)
        tensor, _ = letterbox(frame.image, frame.encoding)
        return {spec.input_name: tensor.copy()}

    def forget_warmup(self) -> None:
        """Leave the untimed warm-up detects out of the counts ``info()`` reports."""
        self.nonfinite.reset()

    def info(self) -> dict[str, Any]:
        facts: dict[str, Any] = {
            'model': str(self.model_path),
            'conf': self.conf,
            'iou': self.iou,
            'max_det': self.max_det,
            'threads': self.options.threads,
            **self.nonfinite.info(),
        }
        spec = self.spec
        if spec is None or self._session is None:
            return facts
        pre = spec.preprocess
        facts.update(
            {
                'model_sha256': spec.sha256,
                'family': spec.family,
                'family_source': spec.family_source,
                'input': {
                    'name': spec.input_name,
                    'shape': list(spec.input_shape),
                    'width': pre.size[0],
                    'height': pre.size[1],
                },
                'input_size': [pre.size[0], pre.size[1]],
                'precision': spec.precision,
                'outputs': [
                    {'name': o.name, 'shape': list(o.shape)} for o in self._session.get_outputs()
                ],
                'num_classes': spec.num_classes,
                'labels_source': spec.labels_source,
                'class_names': list(spec.class_names),
                'preprocess': {
                    'letterbox': pre.letterbox,
                    'align': pre.align,
                    'pad_value': pre.pad_value,
                    'channel_order': pre.channel_order,
                    'scale': pre.scale,
                    'mean': list(pre.mean),
                    'std': list(pre.std),
                },
                'nms': 'in graph'
                if spec.family == 'nms'
                else 'class-aware greedy (numpy), multi-label candidates',
                'metadata': {k: v[:_META_VALUE_CHARS] for k, v in sorted(spec.metadata.items())},
                'quantization': provenance(spec.metadata),
                'engine': 'onnxruntime',
                'onnxruntime': self._ort_version,
                'providers': list(self._providers_used),
                'intra_op_threads': self._intra_threads,
                'intra_op_threads_note': 'onnxruntime default (one per physical core)'
                if self._intra_threads == 0
                else 'from --threads',
                'inter_op_threads': 1,
                'intra_op_spinning': self.spinning,
                'execution_mode': 'sequential',
                'graph_optimization': 'all',
                'cpu_count': os.cpu_count(),
            }
        )
        return facts
