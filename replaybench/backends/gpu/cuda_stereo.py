"""An ONNX stereo network on an NVIDIA GPU (``cuda-stereo``): ``onnx-stereo``'s model through
the ``cuda`` backend's engines, onnxruntime-gpu (IO binding) or PyTorch (onnx2torch).

A backend of the ``stereo`` task that takes frame sets (``--sync``, default ``exact``), as
``onnx-stereo``: each set is a left and a right image, the pair's geometry from their
CameraInfo (``check_frame_set`` before the replay), raw pairs rectified with maps built on the
pair's first set. The model, its layouts (``two-inputs``, ``six-channel``), its options
(``channel_order``, ``scale``, ``max_disparity``) and its output are read as ``onnx-stereo``
reads them; the pipeline is ``_stereo.StereoPipeline``'s.

Rectification stays on the host, with the very maps and ``cv2.remap`` call of ``onnx-stereo``:
the network then sees the same bytes on both backends, so a difference between their
disparities is the engine's (and the device resize's), and for rectified input (``image_rect``
topics, the usual case for a stereo network) there is nothing to do. The remap of a raw
752x480 pair costs about 2 ms on the CPU (docs/stereo.md); on the device it would need the
maps uploaded once and a ``grid_sample``, not bit-equal to OpenCV's fixed-point remap.

Stages per pair, as ``cuda``'s (``StageClock``: host and CUDA-event device times):
``preprocess_ns`` = the host rectification and channel conversion plus the device resize and
scale (``preprocess_device_ns``: the device part); ``h2d`` both images; ``infer`` the engine;
``postprocess`` the resize back and ratio on the device, then the ``Disparity`` on the host;
``d2h`` the image-sized float32 disparity. ``open()`` runs one whole pair (the warm-up).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from replaybench.backends.gpu._cuda import StageClock, device_facts
from replaybench.backends.gpu._fold import pin_host_arguments
from replaybench.backends.gpu._libs import ORT_CUDA_LIBRARIES, load_libraries
from replaybench.backends.gpu._seg import cpu_session
from replaybench.backends.gpu._stereo import (
    StereoOrtEngine,
    StereoPipeline,
    StereoTorchEngine,
    network_channels,
    stereo_facts,
    stereo_output_names,
    torch_stereo_module,
)
from replaybench.backends.gpu._tf32 import Tf32Hold
from replaybench.backends.gpu.availability import GPU_EXTRA, module_missing, ort_provider_problem
from replaybench.backends.gpu.cuda import CudaBackend, torch_events
from replaybench.backends.onnx_stereo import (
    DEFAULT_STEREO_MODEL,
    LAYOUTS,
    load_stereo_spec,
)
from replaybench.backends.sgbm import StereoPairs
from replaybench.errors import BackendError, BackendUnavailableError, StereoError
from replaybench.types import BackendResult, StageTimes

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from replaybench.backends.base import BackendOptions
    from replaybench.backends.onnx_stereo import StereoModelSpec
    from replaybench.types import FrameSet

__all__ = ['STEREO_EXTRA_KEYS', 'CudaStereoBackend']

#: ``onnx-stereo``'s model options, and ``cuda_graph`` (engine torch).
STEREO_EXTRA_KEYS = ('channel_order', 'scale', 'max_disparity', 'cuda_graph', 'rectify_maps')
_SPEC_KEYS = ('channel_order', 'scale', 'max_disparity')


class CudaStereoBackend(StereoPairs, CudaBackend):
    """ONNX stereo models on an NVIDIA GPU; ``options.engine`` picks onnxruntime or torch.

    Options as ``onnx-stereo`` (``--model``, ``--model-family`` two-inputs / six-channel, the
    model options in ``extra``) plus ``cuda``'s ``device``, ``engine``, ``precision`` and
    ``extra['cuda_graph']``. Returns a ``replaybench.stereo.Disparity`` and no detections.
    """

    name: ClassVar[str] = 'cuda-stereo'
    description: ClassVar[str] = (
        'ONNX stereo network on an NVIDIA GPU: onnxruntime-gpu or PyTorch (--model, --sync)'
    )
    task: str = 'stereo'

    def __init__(self, options: BackendOptions | None = None) -> None:
        super().__init__(options)
        self.take_pairs(self.options.extra.get('rectify_maps'))
        self.stereo_spec: StereoModelSpec | None = None
        self._stereo: StereoPipeline | None = None

    @classmethod
    def _accepted_extra_keys(cls) -> tuple[str, ...]:
        return (*STEREO_EXTRA_KEYS, *cls._extra_keys())

    @classmethod
    def _model_families(cls) -> tuple[str, ...]:
        return LAYOUTS

    @classmethod
    def _default_model(cls) -> Path:
        return DEFAULT_STEREO_MODEL

    # -- opening -------------------------------------------------------------------------

    def _read_spec(self, session: Any) -> StereoModelSpec:
        extra = {k: v for k, v in self.options.extra.items() if k in _SPEC_KEYS}
        try:
            return load_stereo_spec(self.model_path, session, self.options.model_family, extra)
        except BackendError as exc:
            msg = f'{self.name}: {exc}'
            raise BackendError(msg) from exc

    def _open_stereo_ort(self, stream: Any) -> tuple[StereoModelSpec, Any, dict[str, Any]]:
        """The session on the GPU provider (checked as ``cuda``'s), the spec and the facts."""
        problem = ort_provider_problem(self.provider)
        if problem is not None:
            raise BackendUnavailableError(problem)
        if self._fp16_needs_fp16_model and self.options.precision == 'fp16':
            msg = (
                f'{self.name}: --precision fp16 needs an fp16 model with engine ort (a stereo '
                'model takes float32); use --engine torch, or tensorrt-stereo'
            )
            raise BackendError(msg)
        load_libraries(ORT_CUDA_LIBRARIES)
        import onnxruntime as ort

        session = self._create_session(stream)
        providers, placement = self._check_session(session)
        spec = self._read_spec(session)
        facts = {
            'onnxruntime': str(ort.__version__),
            'providers': providers,
            'ep_nodes': placement,
            'ort_stream': 'user_compute_stream'
            if getattr(stream, 'cuda_stream', None)
            else 'onnxruntime default',
        }
        return spec, session, facts

    def _open_engine(self, engine: str) -> None:
        torch, device = self._torch_device()
        self._torch, self._device = torch, device
        self._tf32 = Tf32Hold(torch, self._tf32_allowed())
        with torch.cuda.device(device):
            self._stream = torch.cuda.Stream(device=device)
        module: Any = None
        if engine == 'ort':
            spec, session, facts = self._open_stereo_ort(self._stream)
        else:
            missing = [m for m in ('onnx2torch', 'onnx') if module_missing(m)]
            if missing:
                msg = f'{" and ".join(missing)} not installed: {GPU_EXTRA}'
                raise BackendUnavailableError(msg)
            spec = self._read_spec(cpu_session(self.model_path))
            module, facts = torch_stereo_module(self.name, self.model_path, spec, torch)
        half = engine == 'torch' and self.options.precision == 'fp16'
        with torch.cuda.device(device), torch.cuda.stream(self._stream):
            pipeline = StereoPipeline(torch, spec, device, half)
            if engine == 'ort':
                self._engine = StereoOrtEngine(
                    session, spec.input_names, pipeline.inputs, spec.output_name, torch
                )
            else:
                module = module.to(device).eval()
                module = module.half() if half else module.float()
                pinned = pin_host_arguments(module)
                facts['shape_folding']['host_constants'] = len(pinned.pinned)
                facts['shape_folding']['device_shape_reads'] = pinned.dynamic
                order = [spec.input_names.index(n) for n in facts.pop('graph_inputs')]
                self._engine = StereoTorchEngine(
                    torch,
                    module,
                    [pipeline.inputs[i] for i in order],
                    stereo_output_names(self.model_path),
                    self.cuda_graph,
                )
                facts['cuda_graph'] = self._engine.graph_note
                facts['syncs_per_forward'] = self._engine.syncs
        self._stereo, self.stereo_spec = pipeline, spec
        if device.type == 'cuda':
            self._events = torch_events(torch, self._stream)
        self.engine_name = engine
        self.precision = self._precision_name(half)
        gpu = device_facts(self.options.device)
        self._facts = {**self._device_record(torch, gpu), **facts}
        self._facts.update(self._precision_facts(gpu))
        self._warm_up()
        if engine == 'ort':
            from replaybench.backends.gpu.availability import check_session_providers

            self._facts['providers'] = check_session_providers(session, self.provider)

    def _warm_up(self) -> None:
        """One whole pair (grey images of the network's size) through every stage."""
        spec = self.stereo_spec
        assert spec is not None
        width, height = spec.size
        shape = (height, width) if spec.channels == 1 else (height, width, 3)
        image = np.full(shape, 114, dtype=np.uint8)
        began = time.perf_counter_ns()
        self._run_pair((image, image), spec.size)
        self._facts['warmup_ms'] = (time.perf_counter_ns() - began) / 1e6

    def _release(self) -> None:
        super()._release()
        self._stereo = None

    def close(self) -> None:
        super().close()
        self._rectifiers.clear()

    # -- pairs ---------------------------------------------------------------------------

    def detect(self, frame_set: FrameSet) -> BackendResult:  # type: ignore[override]  # a stereo backend takes frame sets
        from replaybench.stereo import Disparity

        if self._engine is None:
            self.open()
        spec = self.stereo_spec
        assert spec is not None
        if len(frame_set.frames) != 2:
            msg = (
                f'{self.name} takes a left and a right image, not {len(frame_set.frames)} '
                f'({", ".join(frame_set.topics)}): give --stereo LEFT,RIGHT'
            )
            raise StereoError(msg)
        left, right = frame_set.frames
        for frame in (left, right):
            if frame.is_depth or frame.encoding == '32FC1':
                msg = (
                    f'{self.name}: frame {frame.topic}#{frame.seq} is a depth image '
                    f'({frame.source_encoding}); replay colour or mono topics only'
                )
                raise BackendError(msg)
        began = time.perf_counter_ns()
        rectifier = self.rectifier(left, right)
        rect_left, rect_right = rectifier.rectify(left.image, right.image)
        images = (
            network_channels(rect_left, left.encoding, spec.channel_order),
            network_channels(rect_right, right.encoding, spec.channel_order),
        )
        on_host = time.perf_counter_ns() - began
        disparity, stages = self._run_pair(images, rectifier.pair.size)
        t0 = time.perf_counter_ns()
        width, height = rectifier.pair.size
        ratio = width / spec.size[0]
        output = Disparity.of_pair(
            disparity,
            rectifier.pair,
            min_disparity=0.0,
            max_disparity=spec.max_disparity * ratio,
            delta_d=0.0,
            valid_window=(0, 0, height, width),
        )
        post_host = time.perf_counter_ns() - t0
        stages = stages._replace(
            preprocess_ns=on_host + (stages.preprocess_ns or 0),
            postprocess_ns=(stages.postprocess_ns or 0) + post_host,
        )
        return BackendResult((), stages, output=output)

    def _run_pair(
        self, images: tuple[npt.NDArray[np.uint8], npt.NDArray[np.uint8]], size: tuple[int, int]
    ) -> tuple[npt.NDArray[np.float32], StageTimes]:
        """Both images through upload, preprocessing, engine and the disparity's resize: the
        image-sized disparity on the host and the stage times (host and device)."""
        torch, pipeline, engine = self._torch, self._stereo, self._engine
        assert pipeline is not None
        assert engine is not None
        clock = StageClock(self._stream.synchronize, self._events)
        if self._tf32 is not None:  # another torch engine opened after this one may differ
            self._tf32.reapply()
        with torch.cuda.device(self._device), torch.cuda.stream(self._stream):
            clock.start()
            staged = pipeline.stage(images)
            clock.begin()
            uploaded = pipeline.transfer(staged)
            h2d = clock.lap()
            clock.begin()
            pipeline.preprocess(uploaded)
            pre = clock.lap()
            clock.begin()
            outputs = engine()
            infer = clock.lap()
            clock.begin()
            try:
                tensor = pipeline.postprocess(outputs, size)
            except BackendError as exc:
                msg = f'{self.name}: {exc}'
                raise BackendError(msg) from exc
            post = clock.lap()
            clock.begin()
            disparity = pipeline.download(tensor)
            d2h = clock.lap()
        on_device = clock.device_laps()
        stages = StageTimes(
            preprocess_ns=pre,
            infer_ns=infer,
            postprocess_ns=post,
            h2d_ns=h2d,
            d2h_ns=d2h,
            preprocess_device_ns=on_device[1],
            infer_device_ns=on_device[2],
            postprocess_device_ns=on_device[3],
            h2d_device_ns=on_device[0],
            d2h_device_ns=on_device[4],
        )
        return disparity, stages

    def info(self) -> dict[str, Any]:
        facts: dict[str, Any] = {
            'task': 'stereo',
            'model': str(self.model_path),
            'engine_requested': self.options.engine,
            'engine': self.engine_name or None,
            'engine_choice': self.engine_choice or None,
            'precision': self.precision or self.options.precision,
            'providers': [],
            'timing': 'host: from the previous stage end, device synchronised at every stage end; '
            'device: a start event before the first and an end event after the last GPU call '
            'of each stage, on the backend stream (frames.csv *_device_ms); preprocess_ms '
            'includes the host rectification and channel conversion',
        }
        spec = self.stereo_spec
        if spec is not None:
            facts.update(stereo_facts(spec))
            facts['rectified'] = self.rectified()
            facts['rectify_maps'] = self.rectify_maps
        facts.update(self._facts)
        return facts
