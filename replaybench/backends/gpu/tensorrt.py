"""The ONNX detector through onnxruntime's TensorRT provider, on an NVIDIA GPU.

The pipeline is the ``cuda`` backend's (pinned upload, torch preprocessing and NMS on the GPU,
IO binding, download of the kept boxes only); inference runs in ``TensorrtExecutionProvider``
(nodes TensorRT cannot take fall to the CUDA provider). ``precision='fp16'`` sets
``trt_fp16_enable``. Built engines are cached in ``$XDG_CACHE_HOME/replaybench/trt``
(default ``~/.cache/replaybench/trt``; ``extra['trt_cache']`` overrides it): the first run
of a model on a GPU builds the engine (seconds to minutes, inside ``open()``), later runs load it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.gpu._cuda import cache_dir
from replaybench.backends.gpu.availability import tensorrt_availability, tensorrt_problem
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.errors import BackendUnavailableError

if TYPE_CHECKING:
    from replaybench.backends.base import Availability, BackendOptions

__all__ = ['TensorrtBackend', 'trt_cache_dir']


def trt_cache_dir(options: BackendOptions) -> Path:
    """Where built TensorRT engines and timing caches are kept."""
    given = options.extra.get('trt_cache', '').strip()
    return Path(given).expanduser() if given else cache_dir('trt')


class TensorrtBackend(CudaBackend):
    """``cuda``'s pipeline with onnxruntime's TensorRT provider for inference."""

    name: ClassVar[str] = 'tensorrt'
    description: ClassVar[str] = (
        'ONNX detector on an NVIDIA GPU through onnxruntime TensorRT (fp16 option, engine cache)'
    )
    engines: ClassVar[tuple[str, ...]] = ('ort',)

    @classmethod
    def _extra_keys(cls) -> tuple[str, ...]:
        return ('trt_cache',)

    @classmethod
    def available(cls) -> Availability:
        return tensorrt_availability()

    def _providers(self) -> list[Any]:
        cache = trt_cache_dir(self.options)
        trt = {
            'device_id': self.options.device,
            'trt_fp16_enable': self.options.precision == 'fp16',
            'trt_engine_cache_enable': True,
            'trt_engine_cache_path': str(cache),
            'trt_timing_cache_enable': True,
            'trt_timing_cache_path': str(cache),
        }
        return [
            ('TensorrtExecutionProvider', trt),
            ('CUDAExecutionProvider', {'device_id': self.options.device}),
            'CPUExecutionProvider',
        ]

    def _open_ort_session(self) -> tuple[Any, list[str], str]:
        problem = tensorrt_problem()
        if problem is not None:
            raise BackendUnavailableError(problem)
        cache = trt_cache_dir(self.options)
        try:
            cache.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            msg = f'cannot create the TensorRT engine cache {cache}: {exc}'
            raise BackendUnavailableError(msg) from None
        return super()._open_ort_session()

    def _open_ort(self) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        # TensorRT takes an fp32 graph and builds fp16 kernels itself: skip cuda's fp16 check.
        requested = self.options.precision
        session, providers, version = self._open_ort_session()
        spec = self._load_spec(session)
        torch, device = self._torch_device()
        facts = {
            'onnxruntime': version,
            'providers': providers,
            'trt_fp16_enable': requested == 'fp16',
            'trt_cache': str(trt_cache_dir(self.options)),
        }
        return spec, torch, device, session, facts

    def info(self) -> dict[str, Any]:
        facts = super().info()
        if self.engine_name:
            facts['precision'] = 'fp16' if self.options.precision == 'fp16' else self.precision
        return facts
