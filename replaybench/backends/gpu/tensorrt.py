"""The ONNX detector through onnxruntime's TensorRT provider, on an NVIDIA GPU.

The pipeline is the ``cuda`` backend's (pinned upload, torch preprocessing and NMS on the GPU,
IO binding, download of the kept boxes only); inference runs in ``TensorrtExecutionProvider``
(nodes TensorRT cannot take go to the CUDA provider, never to the CPU; a session where TensorRT
took no node is refused). ``precision='fp16'`` sets ``trt_fp16_enable``; ``precision='int8'``
sets ``trt_int8_enable``: a model from ``replaybench quantize`` runs with its own scales, a
float one with the calibration cache made from ``extra['calibration_bag']``'s frames
(``_int8``; docs/quantize.md).

TensorRT builds fp32 layers with TF32 on Ampere and newer GPUs unless ``NVIDIA_TF32_OVERRIDE=0``
is in the environment when the process starts (the provider has no option for it), so a
``--precision fp32`` run there is recorded as ``tf32``, with the reason.

Built engines are cached under ``$XDG_CACHE_HOME/replaybench/trt`` (default
``~/.cache/replaybench/trt``; ``extra['trt_cache']`` overrides it), one folder per
``EngineKey``: model hash, TensorRT version, GPU name and compute capability, precision and
input shape. A change in any of them builds a new engine instead of loading a stale one. The
first run of a key builds the engine inside ``open()`` (seconds to minutes); later runs load it.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

from replaybench.backends.gpu._cuda import cache_dir, device_facts
from replaybench.backends.gpu._int8 import (
    CACHE_NAME,
    Holdout,
    build_calibration_cache,
    calibration_batches,
    calibration_id,
    is_quantized,
    parse_holdouts,
)
from replaybench.backends.gpu.availability import (
    tensorrt_availability,
    tensorrt_library_version,
    tensorrt_problem,
)
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.errors import BackendError, BackendUnavailableError

if TYPE_CHECKING:
    from replaybench.backends.base import Availability, BackendOptions
    from replaybench.backends.gpu._cuda import DeviceFacts
    from replaybench.detector.spec import ModelSpec
    from replaybench.segmentation.spec import SegModelSpec

__all__ = ['EngineKey', 'TensorrtBackend', 'engine_folder', 'trt_cache_dir', 'trt_precision']


def trt_cache_dir(options: BackendOptions) -> Path:
    """Where built TensorRT engines and timing caches are kept (one folder per key below)."""
    given = options.extra.get('trt_cache', '').strip()
    return Path(given).expanduser() if given else cache_dir('trt')


class EngineKey(NamedTuple):
    """Everything a built TensorRT engine depends on: a cached one is used only when all match."""

    model_sha256: str
    tensorrt: str
    gpu: str
    compute_capability: str
    precision: str
    input_shape: tuple[int, ...]
    #: int8: ``qdq`` (the model's own scales) or the calibration bag's sha256 and frame count
    calibration: str = ''

    def digest(self) -> str:
        """16 hex digits of the SHA-256 of the key as canonical JSON: the folder name."""
        text = json.dumps(self._asdict(), sort_keys=True, separators=(',', ':'))
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def engine_folder(root: Path, key: EngineKey) -> Path:
    """``root/<digest>``, created, with ``key.json`` naming what its engines were built for."""
    folder = root / key.digest()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        record = folder / 'key.json'
        if not record.is_file():
            text = json.dumps(key._asdict(), indent=2, sort_keys=True) + '\n'
            record.write_text(text, encoding='utf-8')
    except OSError as exc:
        msg = f'cannot create the TensorRT engine cache {folder}: {exc.strerror or exc}'
        raise BackendUnavailableError(msg) from exc
    return folder


def trt_precision(requested: str, compute_capability: str, environ: dict[str, str]) -> str:
    """What TensorRT builds for ``requested``: fp32 turns into tf32 on compute capability 8.0+
    (Ampere and newer) unless ``NVIDIA_TF32_OVERRIDE=0`` is set."""
    if requested != 'fp32':
        return requested
    major = compute_capability.split('.', 1)[0]
    ampere = major.isdigit() and int(major) >= 8
    return 'tf32' if ampere and environ.get('NVIDIA_TF32_OVERRIDE') != '0' else 'fp32'


class TensorrtBackend(CudaBackend):
    """``cuda``'s pipeline with onnxruntime's TensorRT provider for inference."""

    name: ClassVar[str] = 'tensorrt'
    description: ClassVar[str] = (
        'ONNX detector on an NVIDIA GPU through onnxruntime TensorRT (fp16 option, engine cache)'
    )
    engines: ClassVar[tuple[str, ...]] = ('ort',)
    provider: ClassVar[str] = 'TensorrtExecutionProvider'
    # TensorRT takes an fp32 graph and builds fp16 kernels itself.
    _fp16_needs_fp16_model: ClassVar[bool] = False

    def __init__(self, options: BackendOptions | None = None) -> None:
        super().__init__(options)
        self.engine_key: EngineKey | None = None
        self._engine_dir: Path | None = None
        self._profile: dict[str, str] = {}
        self._calibration_cache: Path | None = None

    _int8: ClassVar[bool] = True

    @classmethod
    def _extra_keys(cls) -> tuple[str, ...]:
        return ('trt_cache', 'calibration_bag', 'calibration_frames', 'calibration_holdout')

    @classmethod
    def available(cls) -> Availability:
        return tensorrt_availability()

    def _providers(self, stream: Any = None) -> list[Any]:
        cuda = self._cuda_options(stream)
        folder = str(self._engine_dir) if self._engine_dir is not None else ''
        trt: dict[str, Any] = {
            'device_id': self.options.device,
            'trt_fp16_enable': self.options.precision == 'fp16',
            'trt_engine_cache_enable': True,
            'trt_engine_cache_path': folder,
            'trt_timing_cache_enable': True,
            'trt_timing_cache_path': folder,
            **self._profile,
        }
        if self.options.precision == 'int8':
            trt['trt_int8_enable'] = True
            if self._calibration_cache is not None:
                trt['trt_int8_calibration_table_name'] = self._calibration_cache.name
                trt['trt_int8_use_native_calibration_table'] = True
        if 'user_compute_stream' in cuda:
            trt['has_user_compute_stream'] = 1
            trt['user_compute_stream'] = cuda['user_compute_stream']
        return [('TensorrtExecutionProvider', trt), ('CUDAExecutionProvider', cuda)]

    def _open_ort(self, stream: Any) -> tuple[ModelSpec | SegModelSpec, Any, dict[str, Any]]:
        problem = tensorrt_problem()
        if problem is not None:
            raise BackendUnavailableError(problem)
        spec = self._load_spec(None)
        gpu = device_facts(self.options.device)
        width, height = spec.preprocess.size
        shape = (1, 3, height, width)
        precision = trt_precision(self.options.precision, gpu.compute_capability, dict(os.environ))
        calibration = self._calibration() if precision == 'int8' else None
        key = EngineKey(
            model_sha256=spec.sha256,
            tensorrt=tensorrt_library_version() or 'unknown',
            gpu=gpu.name,
            compute_capability=gpu.compute_capability,
            precision=precision,
            input_shape=shape,
            calibration='' if calibration is None else calibration[0],
        )
        root = trt_cache_dir(self.options)
        folder = engine_folder(root, key)
        cached = sorted(p.name for p in folder.iterdir() if p.name not in ('key.json', CACHE_NAME))
        if calibration is not None and calibration[1] is not None:
            self._calibration_cache = self._calibrate(spec, calibration[1], folder / CACHE_NAME)
        self.engine_key, self._engine_dir = key, folder
        if any(not isinstance(d, int) for d in spec.input_shape):
            # a dynamic input: one optimisation profile, at the size the pipeline feeds
            dims = 'x'.join(str(d) for d in shape)
            profile = f'{spec.input_name}:{dims}'
            self._profile = {
                'trt_profile_min_shapes': profile,
                'trt_profile_opt_shapes': profile,
                'trt_profile_max_shapes': profile,
            }
        spec, session, facts = super()._open_ort(stream)
        facts.update(
            {
                'tensorrt': key.tensorrt,
                'trt_fp16_enable': self.options.precision == 'fp16',
                'trt_cache': str(root),
                'trt_engine_dir': str(folder),
                'trt_engine_key': {**key._asdict(), 'input_shape': list(shape)},
                'trt_engine_cached': bool(cached),
            }
        )
        if precision == 'int8':
            facts['trt_int8_enable'] = True
            facts['int8_calibration'] = (
                {'kind': 'model scales (QDQ)'}
                if self._calibration_cache is None
                else {
                    'kind': 'TensorRT entropy calibration cache',
                    'cache': str(self._calibration_cache),
                    'bag': self.options.extra['calibration_bag'],
                    'frames': self._calibration_frames(),
                    'holdout': [[s, e] for s, e in self._calibration_holdout()],
                }
            )
        return spec, session, facts

    def _calibration_frames(self) -> int:
        text = self.options.extra.get('calibration_frames', '100').strip()
        if not text.isdigit() or int(text) < 1:
            msg = f'{self.name}: calibration_frames must be an integer >= 1, got {text!r}'
            raise BackendError(msg)
        return int(text)

    def _calibration_holdout(self) -> Holdout:
        try:
            return parse_holdouts(self.options.extra.get('calibration_holdout', ''))
        except ValueError as err:
            msg = f'{self.name}: calibration_holdout {err}'
            raise BackendError(msg) from None

    def _calibration(self) -> tuple[str, Path | None]:
        """int8: ``('qdq', None)`` for a quantised model, else the calibration's id and bag."""
        if is_quantized(self.model_path):
            return 'qdq', None
        given = self.options.extra.get('calibration_bag', '').strip()
        if not given:
            msg = (
                f'{self.name}: --precision int8 needs a model from replaybench quantize or a '
                'calibration bag (calibration_bag=BAG in --config; docs/quantize.md)'
            )
            raise BackendError(msg)
        bag = Path(given).expanduser()
        if not bag.exists():
            msg = f'{self.name}: calibration_bag {bag} not found'
            raise BackendError(msg)
        return calibration_id(bag, self._calibration_frames(), self._calibration_holdout()), bag

    def _calibrate(self, spec: ModelSpec | SegModelSpec, bag: Path, cache: Path) -> Path:
        """The engine folder's calibration cache, built once from the bag's frames."""
        if cache.is_file():
            return cache
        try:
            trt = importlib.import_module('tensorrt')
        except ImportError as exc:
            msg = f'{self.name}: INT8 calibration needs the tensorrt module: {exc}'
            raise BackendUnavailableError(msg) from exc
        batches = calibration_batches(
            spec, bag, self._calibration_frames(), self._calibration_holdout()
        )
        return build_calibration_cache(
            trt, self._torch, self.model_path, batches, cache, self._device
        )

    def _precision_name(self, half: bool) -> str:
        if self.engine_key is not None:
            return self.engine_key.precision
        return super()._precision_name(half)

    def _precision_facts(self, gpu: DeviceFacts) -> dict[str, Any]:
        facts = super()._precision_facts(gpu)
        if self.options.precision == 'fp32' and self.precision == 'tf32':
            facts['precision_note'] = (
                f'TensorRT builds fp32 layers with TF32 on compute capability '
                f'{gpu.compute_capability}; start the process with NVIDIA_TF32_OVERRIDE=0 for '
                'strict fp32'
            )
        return facts
