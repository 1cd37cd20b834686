"""The ONNX detector on an NVIDIA GPU: onnxruntime-gpu (IO binding) or PyTorch (onnx2torch).

Per frame, all on one GPU (``options.device``):

* ``h2d``: the frame's pixels copied once into pinned host memory, then to the device;
* ``preprocess``: letterbox resize, padding, channel order, scale/mean/std and HWC->CHW with
  torch ops on the device, written straight into the model's bound input tensor;
* ``infer``: onnxruntime's CUDA provider with the input and outputs bound on the device
  (``engine='ort'``, on the backend's stream through ``user_compute_stream``), or the graph,
  its shapes folded for the fixed input size (``_fold``), converted with onnx2torch and run by
  PyTorch (``engine='torch'``: ``precision='fp16'`` casts it to half, and its forward pass is
  captured as a CUDA graph when capture works);
* ``postprocess``: decode, class-aware greedy NMS (torch ops, no torchvision) and the mapping
  to source pixels on the device, then Detections on the host;
* ``d2h``: only the kept boxes (x0, y0, x1, y1, score, class) come back, with the count of
  candidates left out for NaN or inf model outputs (``info()``: ``nonfinite_dropped``).

A segmentation model (read as ``onnx-seg`` reads it) runs through ``_seg.SegPipeline``: the
argmax on the device, the model-sized label map downloaded, mapped to the frame on the host.

Each stage records a CUDA event on the backend's stream just before its first GPU call and one
after its last, then synchronises the stream before the host clock is read (``StageClock``):
host time per stage from the previous stage's end, device time from start to end event.
``open()`` runs one whole frame (the warm-up). The backend never runs on the CPU: the session
gets the GPU providers only with ``session.disable_cpu_ep_fallback``, and a session whose first
provider is not the GPU one, or with a node placed on the CPU, is refused with
``BackendUnavailableError``. ``precision='fp32'`` keeps TF32 off (torch and the CUDA provider);
``tf32`` allows it.

The engines are ``_engines``'s, the detection pipeline ``_dnn``'s, the segmentation one
``_seg``'s, the upload and preprocessing ``_upload``'s; their public names are importable from
here too.
"""

from __future__ import annotations

import gc
import importlib
import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from replaybench.backends.base import Availability, BackendOptions
from replaybench.backends.gpu._cuda import (
    STAGE_EVENTS,
    DeviceFacts,
    EventTimer,
    StageClock,
    device_facts,
    driver_problem,
)
from replaybench.backends.gpu._dnn import DnnPipeline, to_detections
from replaybench.backends.gpu._engines import (
    OrtEngine,
    TorchEngine,
    count_syncs,
    graph_output_names,
    ortvalue_to_torch,
    torch_module,
)
from replaybench.backends.gpu._fold import pin_host_arguments
from replaybench.backends.gpu._libs import ORT_CUDA_LIBRARIES, load_libraries
from replaybench.backends.gpu._tf32 import Tf32Hold, set_tf32
from replaybench.backends.gpu._upload import frame_input
from replaybench.backends.gpu.availability import (
    GPU_EXTRA,
    check_placement,
    check_session_providers,
    cuda_availability,
    ep_node_counts,
    module_missing,
    ort_cuda_library_problem,
    ort_provider_load_problem,
    ort_provider_problem,
    torch_problem,
)
from replaybench.backends.gpu.choices import ENGINES, PRECISIONS
from replaybench.detector.decoders import NonfiniteTally
from replaybench.detector.spec import (
    DEFAULT_CONF,
    DEFAULT_IOU,
    DEFAULT_MODEL,
    FAMILIES,
    SPEC_KEYS,
)
from replaybench.errors import BackendError, BackendUnavailableError
from replaybench.segmentation.decoder import LAYOUTS
from replaybench.segmentation.spec import SegModelSpec
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from replaybench.backends.gpu._seg import SegPipeline
    from replaybench.detector.spec import ModelSpec
    from replaybench.types import Frame

__all__ = [
    'ENGINES',
    'EXTRA_KEYS',
    'PRECISIONS',
    'CudaBackend',
    'DnnPipeline',
    'OrtEngine',
    'TorchEngine',
    'count_syncs',
    'frame_input',
    'ortvalue_to_torch',
    'set_tf32',
    'to_detections',
    'torch_events',
]

#: Preprocessing overrides (as ``onnx-cpu``), ``size``, ``max_det``, and ``cuda_graph``
#: (``on`` / ``off``; engine torch only) for ``options.extra``.
EXTRA_KEYS = (*SPEC_KEYS, 'max_det', 'cuda_graph')
_SPEC_KEYS = frozenset(SPEC_KEYS)


def _unit(backend: str, name: str, value: float | None) -> None:
    if value is not None and not 0.0 <= value <= 1.0:
        msg = f'{backend}: --{name} must be within 0..1, got {value}'
        raise BackendError(msg)


def torch_events(torch: Any, stream: Any, slots: int = STAGE_EVENTS) -> EventTimer:
    """Timing events on ``stream`` (torch's CUDA events), reused every frame."""
    events = [torch.cuda.Event(enable_timing=True) for _ in range(slots)]
    return EventTimer(events, lambda e: e.record(stream), lambda a, b: a.elapsed_time(b))


class CudaBackend:
    """ONNX detection (or segmentation) models on an NVIDIA GPU; ``options.engine`` picks
    onnxruntime or torch.

    Options as ``onnx-cpu`` (model, family, labels, conf, iou, preprocessing keys in ``extra``)
    plus ``device`` (GPU index), ``engine`` (``auto`` | ``ort`` | ``torch``; auto picks one
    before opening, from what is installed, and never switches after a failure), ``precision``
    (``fp32`` with TF32 off | ``tf32`` | ``fp16``) and ``extra['cuda_graph']``.
    """

    name: ClassVar[str] = 'cuda'
    description: ClassVar[str] = (
        'ONNX detector on an NVIDIA GPU: onnxruntime-gpu (IO binding) or PyTorch (onnx2torch)'
    )
    #: Runs on the GPU ``options.device`` (``Backend.device``).
    device: ClassVar[str] = 'cuda'
    #: Boxes until ``open()`` has read the model: a segmentation model makes it ``segmentation``
    #: (``Backend.task``).
    task: str = 'detections'
    #: Engines this backend may use, in ``auto`` order.
    engines: ClassVar[tuple[str, ...]] = ('ort', 'torch')
    #: The onnxruntime provider the ``ort`` engine must run every node on.
    provider: ClassVar[str] = 'CUDAExecutionProvider'
    #: Engine ``ort`` runs the model in its own precision: fp16 needs an fp16 model.
    _fp16_needs_fp16_model: ClassVar[bool] = True

    def __init__(self, options: BackendOptions | None = None) -> None:
        self.options = options if options is not None else BackendOptions()
        opts = self.options
        _unit(self.name, 'conf', opts.conf)
        _unit(self.name, 'iou', opts.iou)
        if opts.model_family is not None and opts.model_family not in self._model_families():
            known = ', '.join(self._model_families())
            msg = f'{self.name}: unknown --model-family {opts.model_family!r}; known: {known}'
            raise BackendError(msg)
        if opts.engine not in ENGINES:
            msg = f'{self.name}: unknown --engine {opts.engine!r}; known: {", ".join(ENGINES)}'
            raise BackendError(msg)
        if opts.engine != 'auto' and opts.engine not in self.engines:
            offered = ', '.join(self.engines)
            msg = f'{self.name}: --engine {opts.engine} is not offered (only: {offered})'
            raise BackendError(msg)
        if opts.precision not in PRECISIONS:
            known = ', '.join(PRECISIONS)
            msg = f'{self.name}: unknown --precision {opts.precision!r}; known: {known}'
            raise BackendError(msg)
        if opts.precision == 'int8' and not self._int8:
            msg = (
                f"{self.name}: --precision int8 is the tensorrt backend's (docs/quantize.md); "
                f'{self.name} runs fp32, tf32 or fp16'
            )
            raise BackendError(msg)
        if opts.device < 0:
            msg = f'{self.name}: --device must be >= 0, got {opts.device}'
            raise BackendError(msg)
        unknown = sorted(set(opts.extra) - set(self._accepted_extra_keys()))
        if unknown:
            known = ', '.join(self._accepted_extra_keys())
            msg = f'{self.name}: unknown option {unknown[0]!r} (known: {known})'
            raise BackendError(msg)
        self.max_det = 300
        if 'max_det' in opts.extra:
            text = opts.extra['max_det']
            self.max_det = int(text) if text.strip().isdigit() else 0
            if self.max_det < 1:
                msg = f'{self.name}: max_det must be an integer >= 1, got {text!r}'
                raise BackendError(msg)
        graph = opts.extra.get('cuda_graph', 'on').strip().lower()
        if graph not in ('on', 'off', '1', '0', 'true', 'false'):
            msg = f'{self.name}: cuda_graph must be on or off, got {opts.extra["cuda_graph"]!r}'
            raise BackendError(msg)
        self.cuda_graph = graph in ('on', '1', 'true')
        self.model_path: Path = opts.model if opts.model is not None else self._default_model()
        self.iou = opts.iou if opts.iou is not None else DEFAULT_IOU
        self.spec: ModelSpec | SegModelSpec | None = None
        self.engine_name = ''
        self.engine_choice = ''
        self.precision = ''
        self._torch: Any = None
        self._device: Any = None
        self._stream: Any = None
        self._events: EventTimer | None = None
        self._pipeline: DnnPipeline | SegPipeline | None = None
        self._engine: OrtEngine | TorchEngine | None = None
        self._tf32: Tf32Hold | None = None
        self._facts: dict[str, Any] = {}

    #: Whether ``--precision int8`` is offered (``tensorrt``).
    _int8: ClassVar[bool] = False

    @classmethod
    def _extra_keys(cls) -> tuple[str, ...]:
        return ()

    @classmethod
    def _accepted_extra_keys(cls) -> tuple[str, ...]:
        """Every key ``options.extra`` may hold (``cuda-stereo`` takes others)."""
        return (*EXTRA_KEYS, *cls._extra_keys())

    @classmethod
    def _model_families(cls) -> tuple[str, ...]:
        """What ``--model-family`` may name: detector families and segmentation layouts."""
        return (*FAMILIES, *LAYOUTS)

    @classmethod
    def _default_model(cls) -> Path:
        """The model without ``--model``: the bundled detector."""
        return DEFAULT_MODEL

    @classmethod
    def available(cls) -> Availability:
        return cuda_availability()

    # -- engines -------------------------------------------------------------------------

    def choose_engine(self) -> tuple[str, str]:
        """The engine ``open()`` will use and why, decided before anything is opened.

        ``auto`` takes ``ort`` when onnxruntime's build has the provider, else ``torch`` when
        onnx2torch is installed. Whatever fails afterwards is reported, never retried with the
        other engine: a run measures the engine it says it measured.
        """
        requested = self.options.engine
        if requested != 'auto':
            return requested, f'--engine {requested}'
        ort = ort_provider_problem(self.provider)
        if ort is None:
            return 'ort', f'auto: onnxruntime has {self.provider}'
        if 'torch' in self.engines and not module_missing('onnx2torch'):
            return 'torch', f'auto: {ort}; onnx2torch is installed'
        torch = ''
        if 'torch' in self.engines:
            torch = f'; engine torch: onnx2torch is not installed: {GPU_EXTRA}'
        msg = f'{self.name}: no usable GPU engine: engine ort: {ort}{torch}'
        raise BackendUnavailableError(msg)

    def _tf32_allowed(self) -> bool:
        return self.options.precision == 'tf32'

    def _cuda_options(self, stream: Any) -> dict[str, Any]:
        """CUDA provider options: the GPU, TF32 as ``--precision`` says, the backend's stream."""
        options: dict[str, Any] = {
            'device_id': self.options.device,
            'use_tf32': 1 if self._tf32_allowed() else 0,
        }
        handle = getattr(stream, 'cuda_stream', None)
        if handle:
            options['has_user_compute_stream'] = 1
            options['user_compute_stream'] = str(int(handle))
        return options

    def _providers(self, stream: Any = None) -> list[Any]:
        """The session's providers: the GPU ones only (no CPU fallback to fall to)."""
        return [('CUDAExecutionProvider', self._cuda_options(stream))]

    def _create_session(self, stream: Any) -> Any:
        """An onnxruntime session on the GPU providers only, with node placement recorded."""
        import onnxruntime as ort

        so = ort.SessionOptions()
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        so.log_severity_level = 3
        # Every node on the GPU: session creation fails rather than placing one on the CPU.
        so.add_session_config_entry('session.disable_cpu_ep_fallback', '1')
        so.add_session_config_entry('session.record_ep_graph_assignment_info', '1')
        so.add_session_config_entry('session.intra_op.allow_spinning', '0')
        if self.options.threads is not None:
            so.intra_op_num_threads = self.options.threads
        try:
            return ort.InferenceSession(str(self.model_path), so, providers=self._providers(stream))
        except Exception as exc:  # onnxruntime raises several types
            problem = driver_problem(self.options.device)
            if problem is not None:  # e.g. a GPU index beyond the machine
                raise BackendUnavailableError(problem) from exc
            text = f'{type(exc).__name__}: {exc}'
            if 'CPU EP' in str(exc):
                # an unloadable provider leaves every node to the CPU: name what it lacks
                reason = self._provider_load_problem()
                if reason is not None:
                    msg = (
                        f'onnxruntime could not load {self._session_providers()}, so it '
                        f'left the model to the CPU, which this backend refuses: {reason} '
                        f'(onnxruntime: {text})'
                    )
                    raise BackendUnavailableError(msg) from exc
                msg = (
                    f'onnxruntime would run part of {self.model_path.name} on the CPU, which '
                    f'this backend refuses ({text})'
                )
                raise BackendUnavailableError(msg) from exc
            msg = f'cannot load {self.model_path}: {text}'
            raise BackendError(msg) from exc

    def _session_providers(self) -> str:
        return ' / '.join(str(p[0]) for p in self._providers())

    def _provider_load_problem(self) -> str | None:
        """Why onnxruntime cannot load one of the session's GPU providers, or None."""
        for provider in self._providers():
            problem = ort_provider_load_problem(str(provider[0]))
            if problem is not None:
                return problem
        return None

    def _check_session(self, session: Any) -> tuple[list[str], dict[str, int] | None]:
        """The session's providers and nodes per provider; refused unless all is on the GPU."""
        try:
            providers = check_session_providers(session, self.provider)
        except BackendUnavailableError as exc:
            libraries = ort_cuda_library_problem()
            if libraries is None:
                raise
            msg = f'{exc}; {libraries}'
            raise BackendUnavailableError(msg) from exc
        placement = ep_node_counts(session)
        check_placement(placement, self.provider)
        return providers, placement

    def _open_ort(self, stream: Any) -> tuple[ModelSpec | SegModelSpec, Any, dict[str, Any]]:
        """The session on the GPU provider (checked), the model's spec and the facts."""
        problem = ort_provider_problem(self.provider)
        if problem is not None:
            raise BackendUnavailableError(problem)
        # The libraries the CUDA provider links, from the loader's path or the nvidia wheels
        # (importing torch has loaded them already where its CUDA major is the same).
        load_libraries(ORT_CUDA_LIBRARIES)
        import onnxruntime as ort

        session = self._create_session(stream)
        providers, placement = self._check_session(session)
        spec = self._load_spec(session)
        fp16 = self.options.precision == 'fp16'
        if self._fp16_needs_fp16_model and fp16 and spec.precision != 'fp16':
            msg = (
                f'{self.name}: --precision fp16 needs an fp16 model with engine ort '
                '(this one takes fp32); use --engine torch, or the tensorrt backend'
            )
            raise BackendError(msg)
        facts = {
            'onnxruntime': str(ort.__version__),
            'providers': providers,
            'ep_nodes': placement,
            'ort_stream': 'user_compute_stream'
            if getattr(stream, 'cuda_stream', None)
            else 'onnxruntime default',
        }
        return spec, session, facts

    def _open_torch(self, torch: Any) -> tuple[ModelSpec | SegModelSpec, Any, dict[str, Any]]:
        missing = [m for m in ('onnx2torch', 'onnx') if module_missing(m)]
        if missing:
            msg = f'{" and ".join(missing)} not installed: {GPU_EXTRA}'
            raise BackendUnavailableError(msg)
        spec = self._load_spec(None)
        module, facts = torch_module(self.name, self.model_path, spec.preprocess.size, torch)
        return spec, module, facts

    def _torch_device(self) -> tuple[Any, Any]:
        problem = torch_problem(self.options.device)
        if problem is not None:
            raise BackendUnavailableError(problem)
        torch = importlib.import_module('torch')
        return torch, torch.device('cuda', self.options.device)

    def _load_spec(self, session: Any) -> ModelSpec | SegModelSpec:
        from replaybench.backends.gpu import _seg
        from replaybench.detector.spec import load_model_spec

        session = session if session is not None else _seg.cpu_session(self.model_path)
        opts = self.options
        if _seg.is_segmentation(session, opts.model_family):
            return _seg.load_gpu_seg_spec(
                self.model_path, session, opts.model_family, opts.labels, opts.extra
            )
        overrides = {k: v for k, v in self.options.extra.items() if k in _SPEC_KEYS}
        return load_model_spec(
            self.model_path,
            family=self.options.model_family,
            labels=self.options.labels,
            session=session,
            overrides=overrides,
        )

    def _precision_name(self, half: bool) -> str:
        """The precision the model runs in: fp16, tf32 (allowed on request) or strict fp32."""
        if half:
            return 'fp16'
        return 'tf32' if self._tf32_allowed() else 'fp32'

    # -- lifecycle -----------------------------------------------------------------------

    def open(self) -> None:
        """Open the chosen engine and run one whole frame through it (the warm-up)."""
        if self._engine is not None:
            return
        if not self.model_path.is_file():
            what = (
                'the bundled model is not installed' if self.options.model is None else 'not found'
            )
            msg = f'{self.name}: model {self.model_path} {what}; pass --model PATH.onnx'
            raise BackendError(msg)
        engine, why = self.choose_engine()
        self.engine_choice = why
        try:
            self._open_engine(engine)
        except BackendError as exc:
            self._release()
            text = str(exc).removeprefix(f'{self.name}: ')
            hint = ''
            others = [e for e in self.engines if e != engine]
            if self.options.engine == 'auto' and others:
                hint = f' (not switching engines: pass --engine {others[0]} to try it)'
            msg = f'{self.name}: engine {engine} ({why}): {text}{hint}'
            raise type(exc)(msg) from exc
        except BaseException:
            self._release()  # the TF32 hold and device buffers, whatever stopped the open
            raise

    def _open_engine(self, engine: str) -> None:
        torch, device = self._torch_device()
        self._torch, self._device = torch, device
        self._tf32 = Tf32Hold(torch, self._tf32_allowed())
        with torch.cuda.device(device):
            self._stream = torch.cuda.Stream(device=device)
        if engine == 'ort':
            spec, runner, facts = self._open_ort(self._stream)
        else:
            spec, runner, facts = self._open_torch(torch)
        half = spec.precision == 'fp16' or (engine == 'torch' and self.options.precision == 'fp16')
        with torch.cuda.device(device), torch.cuda.stream(self._stream):
            pipeline = self._pipeline_for(torch, spec, device, half)
            if engine == 'ort':
                self._engine = OrtEngine(runner, spec, pipeline.input, torch)
            else:
                module = runner.to(device).eval()
                module = module.half() if half else module.float()
                pinned = pin_host_arguments(module)
                facts['shape_folding']['host_constants'] = len(pinned.pinned)
                facts['shape_folding']['device_shape_reads'] = pinned.dynamic
                self._engine = TorchEngine(
                    torch, module, pipeline.input, graph_output_names(spec), self.cuda_graph
                )
                facts['cuda_graph'] = self._engine.graph_note
                facts['syncs_per_forward'] = self._engine.syncs
        self._pipeline, self.spec = pipeline, spec
        self.task = 'segmentation' if isinstance(spec, SegModelSpec) else 'detections'
        if device.type == 'cuda':
            self._events = torch_events(torch, self._stream)
        self.engine_name = engine
        self.precision = self._precision_name(half)
        gpu = device_facts(self.options.device)
        self._facts = {**self._device_record(torch, gpu), **facts}
        self._facts.update(self._precision_facts(gpu))
        self._warm_up()
        if engine == 'ort':
            # what the session runs on, once more after a real inference
            self._facts['providers'] = check_session_providers(runner, self.provider)

    def _pipeline_for(
        self, torch: Any, spec: ModelSpec | SegModelSpec, device: Any, half: bool
    ) -> DnnPipeline | SegPipeline:
        if isinstance(spec, SegModelSpec):
            from replaybench.backends.gpu._seg import SegPipeline

            return SegPipeline(torch, spec, device, half)
        conf = self.options.conf if self.options.conf is not None else DEFAULT_CONF[spec.family]
        return DnnPipeline(torch, spec, device, half, conf, self.iou, self.max_det)

    def _device_record(self, torch: Any, gpu: DeviceFacts) -> dict[str, Any]:
        """What ``info()`` records of the GPU the backend opened on."""
        return {
            'device': self.options.device,
            'device_name': gpu.name,
            'device_uuid': gpu.uuid,
            'device_pci_bus_id': gpu.pci_bus_id,
            'compute_capability': gpu.compute_capability,
            'driver': gpu.driver,
            'cuda_version': str(torch.version.cuda),
            'device_memory_bytes': gpu.total_memory_bytes,
        }

    def _precision_facts(self, gpu: DeviceFacts) -> dict[str, Any]:  # noqa: ARG002  tensorrt.py's override uses gpu
        return {'precision_requested': self.options.precision, 'tf32': self.precision == 'tf32'}

    def _warm_up(self) -> None:
        """One whole frame (a grey image of the model's input size) through every stage:
        kernels load, engines build, allocators fill before the first frame is timed."""
        assert self.spec is not None
        width, height = self.spec.preprocess.size
        pixels = np.full((height, width, 3), 114, dtype=np.uint8)
        began = time.perf_counter_ns()
        self._run(pixels, 'bgr', 'warm-up')
        self._facts['warmup_ms'] = (time.perf_counter_ns() - began) / 1e6

    def _release(self) -> None:
        """Drop the engine and the device buffers, return cached GPU memory, restore TF32."""
        torch, device = self._torch, self._device
        self._engine = None
        self._pipeline = None
        self._events = None
        if torch is not None:
            if device is not None and device.type == 'cuda' and self._stream is not None:
                self._stream.synchronize()
            self._stream = None
            gc.collect()  # the session / module may sit in a reference cycle
            # torch's caching allocator keeps freed blocks: return them, so that the next
            # backend's GPU memory figure is its own
            torch.cuda.empty_cache()
        self._stream = None
        if self._tf32 is not None:
            self._tf32.release()
            self._tf32 = None

    def close(self) -> None:
        self._release()

    def forget_warmup(self) -> None:
        """Leave the untimed warm-up detects out of the counts ``info()`` reports."""
        if self._pipeline is not None:
            self._pipeline.nonfinite.reset()

    def info(self) -> dict[str, Any]:
        facts: dict[str, Any] = {
            'model': str(self.model_path),
            'engine_requested': self.options.engine,
            'engine': self.engine_name or None,
            'engine_choice': self.engine_choice or None,
            'precision': self.precision or self.options.precision,
            'conf': self._pipeline.conf if self._pipeline is not None else self.options.conf,
            'iou': self.iou,
            'max_det': self.max_det,
            'providers': [],
            'timing': 'host: from the previous stage end, device synchronised at every stage end; '
            'device: a start event before the first and an end event after the last GPU call '
            'of each stage, on the backend stream (frames.csv *_device_ms)',
            **(self._pipeline.nonfinite if self._pipeline else NonfiniteTally()).info(),
        }
        spec = self.spec
        if isinstance(spec, SegModelSpec):
            from replaybench.backends.gpu._seg import seg_facts

            facts.update(seg_facts(spec))
        elif spec is not None:
            facts.update(
                {
                    'model_sha256': spec.sha256,
                    'family': spec.family,
                    'input_size': list(spec.preprocess.size),
                    'class_names': list(spec.class_names),
                    'nms': 'in graph'
                    if spec.family == 'nms'
                    else 'class-aware greedy (torch ops on the GPU), multi-label candidates',
                }
            )
        facts.update(self._facts)
        return facts

    def detect(self, frame: Frame) -> BackendResult:
        if self._engine is None:
            self.open()
        pixels, layout = frame_input(frame, self.name)
        return self._run(pixels, layout, f'{frame.topic}#{frame.seq}')

    def _run(self, pixels: npt.NDArray[np.uint8], layout: str, where: str) -> BackendResult:
        """One frame's pixels through upload, preprocessing, engine and postprocessing."""
        torch, pipeline, engine = self._torch, self._pipeline, self._engine
        assert pipeline is not None
        assert engine is not None
        clock = StageClock(self._stream.synchronize, self._events)
        if self._tf32 is not None:  # another torch engine opened after this one may differ
            self._tf32.reapply()
        with torch.cuda.device(self._device), torch.cuda.stream(self._stream):
            clock.start()
            staged = pipeline.stage(pixels)
            clock.begin()
            image = pipeline.transfer(staged)
            h2d = clock.lap()
            try:
                transform = pipeline.preprocess(image, layout, clock.begin)
            except BackendError as exc:
                msg = f'{self.name}: frame {where}: {exc}'
                raise BackendError(msg) from exc
            pre = clock.lap()
            clock.begin()
            outputs = engine()
            infer = clock.lap()
            clock.begin()
            tensors = pipeline.postprocess(outputs, transform)
            post_device = clock.lap()
            clock.begin()
            arrays = pipeline.download(tensors)
            d2h = clock.lap()
        on_device = clock.device_laps()
        t0 = time.perf_counter_ns()
        detections, mask = pipeline.answer(arrays, transform)
        post_host = time.perf_counter_ns() - t0
        stages = StageTimes(
            preprocess_ns=pre,
            infer_ns=infer,
            postprocess_ns=post_device + post_host,
            h2d_ns=h2d,
            d2h_ns=d2h,
            preprocess_device_ns=on_device[1],
            infer_device_ns=on_device[2],
            postprocess_device_ns=on_device[3],
            h2d_device_ns=on_device[0],
            d2h_device_ns=on_device[4],
        )
        return BackendResult(detections, stages, mask)
