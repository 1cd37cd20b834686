"""The torch engine's forward reads nothing from the device on the host once shapes are folded.

No GPU here, so device -> host synchronisations are counted where torch would make them: every
tensor the model holds on the device (its input, parameters and buffers, except the constants
``pin_host_arguments`` keeps in host memory) is marked, marks spread to every result computed
from a marked tensor, and each host read of a marked tensor (``.item()``, ``.tolist()``,
``.cpu()``, ``bool()`` / ``int()`` / index use) counts one synchronisation, as it would on a
GPU. The converted models run for real on the CPU; folding must not change their outputs.
"""

from __future__ import annotations

import importlib.util
from collections import Counter
from typing import Any

import numpy as np
import pytest

from replaybench.backends.gpu._engines import import_onnx2torch
from replaybench.backends.gpu._fold import fold_shapes, pin_host_arguments
from replaybench.errors import BackendError

torch = pytest.importorskip('torch')
onnx = pytest.importorskip('onnx')
if importlib.util.find_spec('onnx2torch') is None:
    pytest.skip('onnx2torch is not installed (make install)', allow_module_level=True)

from torch.overrides import TorchFunctionMode  # noqa: E402 - after the skips

#: Host reads of a tensor: each one a device -> host synchronisation for a CUDA tensor.
HOST_READS = frozenset(
    {'tolist', 'item', '__bool__', '__int__', '__index__', '__float__', 'cpu', 'numpy'}
)


class HostReads(TorchFunctionMode):
    """Counts host reads of tensors that live on the (stand-in) device."""

    def __init__(self, on_device: list[Any]) -> None:
        super().__init__()
        self.counts: Counter[str] = Counter()
        for tensor in on_device:
            tensor._on_device = True

    @staticmethod
    def _tensors(value: Any) -> list[Any]:
        if isinstance(value, torch.Tensor):
            return [value]
        if isinstance(value, list | tuple):
            return [t for v in value for t in HostReads._tensors(v)]
        if isinstance(value, dict):
            return [t for v in value.values() for t in HostReads._tensors(v)]
        return []

    def __torch_function__(self, func: Any, types: Any, args: Any = (), kwargs: Any = None) -> Any:
        kwargs = kwargs or {}
        marked = any(getattr(t, '_on_device', False) for t in self._tensors((args, kwargs)))
        name = getattr(func, '__name__', '')
        read = marked and name in HOST_READS
        if read and name != 'numpy':  # .numpy() needs .cpu() first on a GPU: counted there
            self.counts[name] += 1
        out = func(*args, **kwargs)
        if marked and not read:
            for tensor in self._tensors(out):
                tensor._on_device = True
        return out


def _model(which: str) -> Any:
    from backends.gpu.gpuhelpers import YOLOX_NANO

    from replaybench.detector.spec import DEFAULT_MODEL

    path = DEFAULT_MODEL if which == 'bundled' else YOLOX_NANO
    if not path.is_file():
        pytest.skip(f'{path} is not present')
    return onnx.load(str(path))


def _input_shape(proto: Any) -> list[int]:
    return [d.dim_value for d in proto.graph.input[0].type.tensor_type.shape.dim]


def _run(module: Any, x: Any, pinned: tuple[str, ...] = ()) -> tuple[int, Any]:
    buffers = dict(module.named_buffers())
    on_device = [x, *module.parameters(), *(b for n, b in buffers.items() if n not in pinned)]
    with torch.inference_mode(), HostReads(on_device) as mode:
        out = module(x)
    for tensor in on_device:
        del tensor._on_device
    first = out[0] if isinstance(out, list | tuple) else out
    return sum(mode.counts.values()), first.detach().numpy()


@pytest.mark.parametrize('which', ['bundled', 'yolox_nano'])
def test_folded_shapes_leave_no_host_read_in_the_forward_pass(which):
    onnx2torch, _ = import_onnx2torch()
    proto = _model(which)
    shape = _input_shape(proto)
    x = torch.from_numpy(np.random.default_rng(0).random(shape, dtype=np.float32))

    plain = onnx2torch.convert(proto).eval()
    reads_before, expected = _run(plain, x)

    folded, report = fold_shapes(onnx, proto, shape)
    module = onnx2torch.convert(folded).eval()
    pinned = pin_host_arguments(module)
    reads_after, got = _run(module, x, pinned.pinned)

    assert reads_before > 0  # 14 for the bundled model, 30 for YOLOX-Nano (onnx2torch 1.5.15)
    assert reads_after == 0
    assert pinned.dynamic == 0
    assert report.shape_ops_left == 0
    np.testing.assert_array_equal(got, expected)


def test_the_shape_arithmetic_of_the_bundled_model_is_folded_into_constants():
    proto = _model('bundled')
    ops_before = Counter(n.op_type for n in proto.graph.node)
    folded, report = fold_shapes(onnx, proto, _input_shape(proto))
    ops_after = Counter(n.op_type for n in folded.graph.node)
    assert ops_before['Shape'] == 1
    assert ops_after['Shape'] == 0
    assert ops_after['Constant'] == 0
    assert report.folded['Shape'] == 1
    assert report.total == sum(ops_before.values()) - sum(ops_after.values())
    assert ops_after['Conv'] == ops_before['Conv']
    onnx.checker.check_model(folded)


def test_a_dynamic_input_is_fixed_at_the_size_the_pipeline_feeds(tiny_model):
    proto = onnx.load(str(tiny_model))
    dims = proto.graph.input[0].type.tensor_type.shape.dim
    dims[0].dim_param = 'batch'
    folded, _ = fold_shapes(onnx, proto, (1, 3, 32, 64))
    fixed = [d.dim_value for d in folded.graph.input[0].type.tensor_type.shape.dim]
    assert fixed == [1, 3, 32, 64]
    assert proto.graph.input[0].type.tensor_type.shape.dim[0].dim_param == 'batch'  # a copy


def test_a_fixed_input_of_another_size_is_refused(tiny_model):
    proto = onnx.load(str(tiny_model))
    with pytest.raises(BackendError, match=r'is fixed at \[1, 3, 32, 64\], not \[1, 3, 64, 64\]'):
        fold_shapes(onnx, proto, (1, 3, 64, 64))
