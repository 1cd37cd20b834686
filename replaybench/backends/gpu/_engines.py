"""The inference engines of ``cuda`` / ``tensorrt``, on tensors already on the device.

* ``OrtEngine``: an onnxruntime session run with IO binding: the input and the outputs stay on
  the device (outputs viewed as torch tensors without a copy: ``ortvalue_to_torch``);
* ``TorchEngine``: the ONNX graph, its shapes folded for the fixed input size (``_fold``),
  converted with onnx2torch (``torch_module``) and run by PyTorch, its forward pass captured as
  a CUDA graph when capture works (``count_syncs`` counts what would stop it).
"""

from __future__ import annotations

import importlib
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.backends.gpu._fold import fold_shapes
from replaybench.errors import BackendError, BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    from replaybench.detector.spec import ModelSpec
    from replaybench.segmentation.spec import SegModelSpec

__all__ = [
    'TORCHVISION_OPS',
    'OrtEngine',
    'TorchEngine',
    'count_syncs',
    'graph_output_names',
    'import_onnx2torch',
    'ortvalue_to_torch',
    'torch_module',
]

#: onnxruntime element types (TensorProto) -> numpy type strings, for the pointer fallback.
_ORT_TYPES = {1: '<f4', 6: '<i4', 7: '<i8', 9: '|b1', 10: '<f2', 11: '<f8'}
Tensor = Any  # torch.Tensor


class _DevicePointer:
    """``__cuda_array_interface__`` over a raw device buffer (an onnxruntime output)."""

    def __init__(self, ptr: int, shape: Sequence[int], typestr: str) -> None:
        self.__cuda_array_interface__ = {
            'shape': tuple(shape),
            'typestr': typestr,
            'data': (ptr, False),
            'version': 2,
        }


def ortvalue_to_torch(torch: Any, value: Any, device: Any) -> Tensor:
    """A torch view of an onnxruntime ``OrtValue`` output without a copy.

    DLPack where the onnxruntime build offers it; else the raw pointer (CUDA) or numpy (CPU).
    The ``OrtValue`` must outlive the tensor.
    """
    if hasattr(value, '__dlpack__'):
        return torch.from_dlpack(value)
    if device.type == 'cpu':
        return torch.from_numpy(value.numpy())
    typestr = _ORT_TYPES.get(int(value.element_type()))
    if typestr is None:
        msg = f'unsupported onnxruntime output type {value.data_type()}'
        raise BackendError(msg)
    wrapper = _DevicePointer(int(value.data_ptr()), list(value.shape()), typestr)
    return torch.as_tensor(wrapper, device=device)


class OrtEngine:
    """onnxruntime session run with IO binding: input and outputs stay on the device."""

    def __init__(
        self, session: Any, spec: ModelSpec | SegModelSpec, input_tensor: Tensor, torch: Any
    ) -> None:
        self.torch = torch
        self.session = session
        self.names = list(spec.output_names)
        self.device = input_tensor.device
        kind = 'cuda' if self.device.type == 'cuda' else 'cpu'
        index = self.device.index or 0
        dtype = np.float16 if input_tensor.dtype == torch.float16 else np.float32
        binding = session.io_binding()
        binding.bind_input(
            spec.input_name, kind, index, dtype, list(input_tensor.shape), input_tensor.data_ptr()
        )
        for name in self.names:
            binding.bind_output(name, kind, index)
        self.binding = binding
        self._values: list[Any] = []

    def __call__(self) -> dict[str, Tensor]:
        try:
            self.session.run_with_iobinding(self.binding)
        except Exception as exc:  # onnxruntime errors have several types
            msg = f'inference failed: {type(exc).__name__}: {exc}'
            raise BackendError(msg) from exc
        self.binding.synchronize_outputs()
        self._values = self.binding.get_outputs()  # keeps the device buffers alive
        return {
            name: ortvalue_to_torch(self.torch, value, self.device)
            for name, value in zip(self.names, self._values, strict=True)
        }


#: ONNX ops that onnx2torch implements with torchvision.
TORCHVISION_OPS = frozenset({'NonMaxSuppression', 'RoiAlign'})


def import_onnx2torch() -> tuple[Any, Any]:
    """``(onnx2torch, torchvision or None)``.

    onnx2torch imports torchvision at import time, but uses it only for the
    ``NonMaxSuppression`` and ``RoiAlign`` converters. Without torchvision (a CPU build of torch
    has no matching one on PyPI) it is imported against a placeholder that is removed right
    after, and ``_open_torch`` refuses models with those two ops.
    """
    import sys
    import types

    try:
        return importlib.import_module('onnx2torch'), importlib.import_module('torchvision')
    except ModuleNotFoundError as exc:
        if exc.name != 'torchvision':
            raise
    for name in [m for m in sys.modules if m == 'onnx2torch' or m.startswith('onnx2torch.')]:
        del sys.modules[name]

    def missing(*_args: object, **_kwargs: object) -> Any:
        msg = 'torchvision is not installed'
        raise BackendError(msg)

    placeholder = types.ModuleType('torchvision')
    placeholder_ops = types.ModuleType('torchvision.ops')
    for attr in ('nms', 'box_convert', 'roi_align'):
        setattr(placeholder_ops, attr, missing)
    placeholder.ops = placeholder_ops  # type: ignore[attr-defined]
    sys.modules['torchvision'] = placeholder
    sys.modules['torchvision.ops'] = placeholder_ops
    try:
        return importlib.import_module('onnx2torch'), None
    finally:
        del sys.modules['torchvision'], sys.modules['torchvision.ops']


def count_syncs(torch: Any, call: Callable[[], object]) -> int | None:
    """Device -> host synchronisations ``call`` makes, counted by torch's sync debug mode
    (each one a warning); None where this torch has no such mode."""
    mode = getattr(torch.cuda, 'set_sync_debug_mode', None)
    if mode is None:
        return None
    previous = torch.cuda.get_sync_debug_mode()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        mode('warn')
        try:
            call()
        finally:
            mode(previous)
    return sum('synchroniz' in str(w.message).lower() for w in caught)


class TorchEngine:
    """A torch module (the ONNX graph converted by onnx2torch) on the input tensor.

    With ``cuda_graph`` the forward pass is captured once and replayed each frame; a forward
    that synchronises with the host (``syncs`` > 0, counted first) is not captured, since a
    capture fails on it; when capture fails for another reason it runs eagerly too, and
    ``graph_note`` says why. Warm-up and capture run on a side stream made on the input's
    device, passed to ``torch.cuda.graph`` (whose own default is a process-wide stream made on
    whichever device was current first).
    """

    def __init__(
        self, torch: Any, module: Any, input_tensor: Tensor, names: Sequence[str], cuda_graph: bool
    ) -> None:
        self.torch = torch
        self.module = module
        self.input = input_tensor
        self.names = list(names)
        self.graph: Any = None
        self.static: list[Tensor] = []
        self.graph_note = 'off'
        #: Device -> host synchronisations of one eager forward (CUDA only), as torch counts them.
        self.syncs: int | None = None
        if input_tensor.device.type == 'cuda':
            self.syncs = count_syncs(torch, self._forward)
            if cuda_graph:
                self._capture()

    def _forward(self) -> list[Tensor]:
        with self.torch.inference_mode():
            out = self.module(self.input)
        return list(out) if isinstance(out, list | tuple) else [out]

    def _capture(self) -> None:
        torch = self.torch
        if self.syncs:
            self.graph_note = (
                f'eager (the forward synchronises with the host {self.syncs} time(s), which a '
                'CUDA graph cannot capture)'
            )
            return
        try:
            side = torch.cuda.Stream(device=self.input.device)
            side.wait_stream(torch.cuda.current_stream(self.input.device))
            with torch.cuda.stream(side):
                for _ in range(3):
                    self._forward()
            torch.cuda.current_stream(self.input.device).wait_stream(side)
            graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(graph, stream=side):
                self.static = self._forward()
        except Exception as exc:  # noqa: BLE001  capture is an optimisation: eager mode
            torch.cuda.synchronize(self.input.device)
            self.graph = None
            self.static = []
            self.graph_note = f'eager (capture failed: {type(exc).__name__}: {exc})'[:300]
            return
        self.graph = graph
        self.graph_note = 'captured'

    def __call__(self) -> dict[str, Tensor]:
        if self.graph is not None:
            self.graph.replay()
            outputs = self.static
        else:
            outputs = self._forward()
        if len(outputs) < len(self.names):
            msg = f'the converted model returned {len(outputs)} outputs, expected {len(self.names)}'
            raise BackendError(msg)
        return dict(zip(self.names, outputs, strict=False))


def torch_module(
    name: str, model_path: Path, size: tuple[int, int], torch: Any
) -> tuple[Any, dict[str, Any]]:
    """The model at ``model_path`` as a torch module: its shapes folded for the input ``size``
    (width, height), converted by onnx2torch; and the facts ``info()`` reports of it.

    ``BackendUnavailableError`` for a model that needs torchvision where there is none,
    ``BackendError`` for one whose shapes do not fold or that onnx2torch cannot convert.
    """
    onnx = importlib.import_module('onnx')
    proto = onnx.load(str(model_path))
    onnx2torch, torchvision = import_onnx2torch()
    needs = sorted({n.op_type for n in proto.graph.node} & TORCHVISION_OPS)
    if needs and torchvision is None:
        msg = (
            f'{name}: {model_path.name} has {", ".join(needs)} nodes, which '
            'onnx2torch runs with torchvision; torchvision is not installed'
        )
        raise BackendUnavailableError(msg)
    width, height = size
    try:
        proto, report = fold_shapes(onnx, proto, (1, 3, height, width))
    except BackendError as exc:
        msg = f'{name}: cannot fold the shapes of {model_path.name}: {exc}'
        raise BackendError(msg) from exc
    try:
        module = onnx2torch.convert(proto)
    except Exception as exc:  # unsupported ops and the like
        what = f'{type(exc).__name__}: {exc}'
        msg = f'{name}: onnx2torch cannot convert {model_path}: {what}'
        raise BackendError(msg) from exc
    facts = {
        'torch': str(torch.__version__),
        'onnx2torch': _version('onnx2torch'),
        'torchvision': _version('torchvision') if torchvision is not None else None,
        'shape_folding': {
            'input_shape': [1, 3, height, width],
            'folded_nodes': report.folded,
            'shape_ops_left': report.shape_ops_left,
        },
    }
    return module, facts


def graph_output_names(spec: ModelSpec | SegModelSpec) -> list[str]:
    """Names of all graph outputs in graph order (onnx2torch returns them in this order)."""
    onnx = importlib.import_module('onnx')
    model = onnx.load(str(spec.path), load_external_data=False)
    return [o.name for o in model.graph.output]


def _version(module: str) -> str | None:
    import importlib.metadata

    try:
        return importlib.metadata.version(module)
    except importlib.metadata.PackageNotFoundError:
        return None
