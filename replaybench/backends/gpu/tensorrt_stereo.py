"""An ONNX stereo network through onnxruntime's TensorRT provider (``tensorrt-stereo``).

``cuda-stereo``'s pipeline (rectification on the host, both images uploaded, resize and scale
on the device, the disparity resized back on the device) with ``tensorrt``'s provider set-up:
TensorRT first, the CUDA provider for nodes it cannot take, never the CPU; a session where
TensorRT took no node is refused; ``--precision fp16`` sets ``trt_fp16_enable``; built engines
cached per ``EngineKey`` (the key's input shape is the left image's input, ``[1, C, H, W]``, or
the one 6-channel input; a stereo model's input sizes are fixed).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, ClassVar

from replaybench.backends.gpu import availability
from replaybench.backends.gpu._cuda import device_facts
from replaybench.backends.gpu._seg import cpu_session
from replaybench.backends.gpu.cuda_stereo import CudaStereoBackend
from replaybench.backends.gpu.tensorrt import (
    EngineKey,
    TensorrtBackend,
    engine_folder,
    trt_cache_dir,
    trt_precision,
)
from replaybench.errors import BackendUnavailableError

if TYPE_CHECKING:
    from replaybench.backends.onnx_stereo import StereoModelSpec

__all__ = ['TensorrtStereoBackend']


class TensorrtStereoBackend(CudaStereoBackend, TensorrtBackend):
    """``cuda-stereo``'s pipeline with onnxruntime's TensorRT provider for inference."""

    name: ClassVar[str] = 'tensorrt-stereo'
    description: ClassVar[str] = (
        'ONNX stereo network on an NVIDIA GPU through onnxruntime TensorRT (--model, --sync)'
    )

    def _open_stereo_ort(self, stream: Any) -> tuple[StereoModelSpec, Any, dict[str, Any]]:
        problem = availability.tensorrt_problem()
        if problem is not None:
            raise BackendUnavailableError(problem)
        spec = self._read_spec(cpu_session(self.model_path))
        gpu = device_facts(self.options.device)
        shape = tuple(spec.input_shapes[0])
        precision = trt_precision(self.options.precision, gpu.compute_capability, dict(os.environ))
        key = EngineKey(
            model_sha256=spec.sha256,
            tensorrt=availability.tensorrt_library_version() or 'unknown',
            gpu=gpu.name,
            compute_capability=gpu.compute_capability,
            precision=precision,
            input_shape=shape,
        )
        root = trt_cache_dir(self.options)
        folder = engine_folder(root, key)
        cached = sorted(p.name for p in folder.iterdir() if p.name != 'key.json')
        self.engine_key, self._engine_dir = key, folder
        spec, session, facts = super()._open_stereo_ort(stream)
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
        return spec, session, facts
