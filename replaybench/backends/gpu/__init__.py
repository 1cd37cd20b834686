"""GPU backends: ``cuda`` (ONNX detector via onnxruntime-gpu or PyTorch), ``tensorrt``
(onnxruntime's TensorRT provider) and ``hsv-cuda`` (the hsv detector with CuPy).

Importing this package or its backend modules imports neither torch nor CuPy; they are
imported by ``open()``, and by ``available()`` only once an NVIDIA driver is found.
See docs/gpu.md.
"""

from __future__ import annotations

__all__: list[str] = []
