"""Shapes folded for one fixed input size, so that the torch engine's forward never reads the
device from the host.

onnx2torch turns shape arithmetic (``Shape -> Gather -> Concat -> Reshape``) and the shape
inputs of ``Reshape`` / ``Slice`` / ``Resize`` / ... into tensors that its modules read with
``.tolist()``, ``int()`` or ``.cpu()`` on every forward: on a GPU each read is a device ->
host synchronisation (about 30 for YOLOX-Nano), and CUDA-graph capture fails on them. Two steps
remove them for a fixed input size:

1. ``fold_shapes``: the input's dimensions fixed, ONNX shape inference, then every ``Shape`` /
   ``Size`` of a static tensor and every node whose inputs are all constants evaluated once
   (``onnx.reference``) and replaced by an initializer, until nothing changes;
2. ``pin_host_arguments``: after onnx2torch, the constants that only feed shape arguments
   (``Reshape``'s shape, ``Slice``'s starts / ends / axes / steps, ``Resize``'s scales / sizes,
   ...) are kept in host memory, where reading them costs no synchronisation.

onnx and torch are passed in by the caller; importing this module imports neither.
"""

from __future__ import annotations

import inspect
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from replaybench.errors import BackendError

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['HOST_ARGUMENTS', 'FoldReport', 'PinReport', 'fold_shapes', 'pin_host_arguments']

#: onnx2torch modules and their arguments (``forward`` parameter names) read on the host.
HOST_ARGUMENTS: dict[str, tuple[str, ...]] = {
    'OnnxReshape': ('shape',),
    'OnnxSlice': ('starts', 'ends', 'axes', 'steps'),
    'OnnxResize': ('roi', 'scales', 'sizes'),
    'OnnxResizeV10': ('scales',),
    'OnnxExpand': ('shape',),
    'OnnxTile': ('repeats',),
    'OnnxConstantOfShape': ('shape',),
    'OnnxPadDynamic': ('pads',),
    'OnnxUnsqueezeDynamicAxes': ('axes',),
    'OnnxSqueezeDynamicAxes': ('axes',),
    'OnnxSplit13': ('split',),
    'OnnxReduceSumDynamicAxes': ('axes',),
    'OnnxCumSum': ('axis',),
    'OnnxTopK': ('k',),
}
#: Ops never evaluated ahead: random ones, and those with subgraphs.
_NEVER_FOLD = frozenset(
    {
        'RandomNormal',
        'RandomUniform',
        'RandomNormalLike',
        'RandomUniformLike',
        'Multinomial',
        'Bernoulli',
        'If',
        'Loop',
        'Scan',
        'SequenceMap',
    }
)
#: A folded constant holds at most this many elements (no large tensors materialised).
MAX_FOLDED_ELEMENTS = 1 << 20


class FoldReport(NamedTuple):
    """What ``fold_shapes`` did: nodes folded per op type, and shape ops left in the graph."""

    folded: dict[str, int]
    shape_ops_left: int

    @property
    def total(self) -> int:
        return sum(self.folded.values())


def _static_dims(value_type: Any) -> tuple[int, ...] | None:
    """The dimensions of a tensor type when every one is a number, else None."""
    if not value_type.HasField('tensor_type') or not value_type.tensor_type.HasField('shape'):
        return None
    dims = []
    for dim in value_type.tensor_type.shape.dim:
        if not dim.HasField('dim_value'):
            return None
        dims.append(int(dim.dim_value))
    return tuple(dims)


def _fix_input(graph: Any, initializers: set[str], shapes: Sequence[Sequence[int]]) -> None:
    """Fix the graph inputs (in graph order) at ``shapes``, one shape per input."""
    inputs = [i for i in graph.input if i.name not in initializers]
    if len(inputs) != len(shapes):
        count = 'one graph input' if len(shapes) == 1 else f'{len(shapes)} graph inputs'
        msg = f'expected {count}, the model has {len(inputs)}'
        raise BackendError(msg)
    for graph_input, shape in zip(inputs, shapes, strict=True):
        dims = graph_input.type.tensor_type.shape.dim
        if len(dims) != len(shape):
            msg = f'input {graph_input.name!r} has {len(dims)} dimensions, not {len(shape)}'
            raise BackendError(msg)
        for dim, size in zip(dims, shape, strict=True):
            if dim.HasField('dim_value') and int(dim.dim_value) != int(size):
                msg = (
                    f'input {graph_input.name!r} is fixed at {_dims_text(dims)}, not {list(shape)}'
                )
                raise BackendError(msg)
            dim.Clear()
            dim.dim_value = int(size)


def _dims_text(dims: Any) -> str:
    return str([d.dim_value if d.HasField('dim_value') else d.dim_param or '?' for d in dims])


def _shape_of(node: Any, shape: tuple[int, ...]) -> np.ndarray:
    """``Shape`` (with opset 15's ``start`` / ``end``) of a tensor of ``shape``."""
    start, end = 0, len(shape)
    for attr in node.attribute:
        if attr.name == 'start':
            start = int(attr.i)
        elif attr.name == 'end':
            end = int(attr.i)
    return np.array(shape[slice(start, end)], dtype=np.int64)


def _evaluate(node: Any, feeds: dict[str, np.ndarray], opset: int) -> list[Any] | None:
    """The outputs of one node on constant inputs, None when onnx's reference cannot run it."""
    from onnx.reference import ReferenceEvaluator

    try:
        outputs = ReferenceEvaluator(node, opsets={'': opset}).run(None, feeds)
    except Exception:  # noqa: BLE001  an op the reference does not implement: the node stays
        return None
    values = [np.asarray(v) for v in outputs]
    if any(v.dtype == object or v.size > MAX_FOLDED_ELEMENTS for v in values):
        return None
    return values


def fold_shapes(onnx: Any, model: Any, *input_shapes: Sequence[int]) -> tuple[Any, FoldReport]:
    """A copy of ``model`` with its inputs fixed at ``input_shapes`` (one per graph input, in
    graph order: a detector's one, a stereo model's two) and its shape arithmetic (and any
    other all-constant node) folded into initializers."""
    from onnx import numpy_helper, shape_inference

    folded_model = onnx.ModelProto()
    folded_model.CopyFrom(model)
    graph = folded_model.graph
    constants = {init.name: numpy_helper.to_array(init) for init in graph.initializer}
    _fix_input(graph, set(constants), input_shapes)
    opset = next((o.version for o in folded_model.opset_import if o.domain in ('', 'ai.onnx')), 0)
    if opset == 0:
        msg = 'the model imports no default ONNX opset'
        raise BackendError(msg)
    graph_outputs = {o.name for o in graph.output}
    folded: dict[str, int] = {}
    changed = True
    while changed:
        changed = False
        shapes: dict[str, tuple[int, ...]] = {}
        try:
            inferred = shape_inference.infer_shapes(folded_model, data_prop=True)
        except Exception:  # noqa: BLE001  inference is a help: without it only constants fold
            inferred = None
        if inferred is not None:
            for info in (*inferred.graph.input, *inferred.graph.value_info):
                dims = _static_dims(info.type)
                if dims is not None:
                    shapes[info.name] = dims
        kept = []
        for node in graph.node:
            values = _fold_node(node, constants, shapes, opset)
            if values is None or any(name in graph_outputs for name in node.output):
                kept.append(node)
                continue
            constants.update(zip(node.output, values, strict=True))
            folded[node.op_type] = folded.get(node.op_type, 0) + 1
            changed = True
        if changed:
            del graph.node[:]
            graph.node.extend(kept)
            _rebuild_initializers(graph, constants)
    left = sum(node.op_type in ('Shape', 'Size') for node in graph.node)
    return folded_model, FoldReport(dict(sorted(folded.items())), left)


def _fold_node(
    node: Any,
    constants: dict[str, np.ndarray],
    shapes: dict[str, tuple[int, ...]],
    opset: int,
) -> list[Any] | None:
    if node.domain not in ('', 'ai.onnx') or node.op_type in _NEVER_FOLD:
        return None
    inputs = [name for name in node.input if name]
    if node.op_type in ('Shape', 'Size') and inputs:
        source = inputs[0]
        shape = constants[source].shape if source in constants else shapes.get(source)
        if shape is None:
            return None
        if node.op_type == 'Size':
            return [np.array(int(np.prod(shape, dtype=np.int64)), dtype=np.int64)]
        return [_shape_of(node, tuple(int(d) for d in shape))]
    if not all(name in constants for name in inputs):
        return None
    feeds = {name: constants[name] for name in inputs}
    return _evaluate(node, feeds, opset)


def _rebuild_initializers(graph: Any, constants: dict[str, np.ndarray]) -> None:
    """Initializers: the constants still read by a node or a graph output."""
    from onnx import numpy_helper

    used = {name for node in graph.node for name in node.input}
    used |= {o.name for o in graph.output}
    del graph.initializer[:]
    graph.initializer.extend(
        numpy_helper.from_array(np.asarray(value), name)
        for name, value in constants.items()
        if name in used
    )
    names = {init.name for init in graph.initializer}
    stale = [i for i in graph.input if i.name in constants and i.name not in names]
    for info in stale:
        graph.input.remove(info)


class PinReport(NamedTuple):
    """What ``pin_host_arguments`` did: the constants now in host memory (``module``-relative
    buffer names), and the host-read arguments still computed on the device (each a
    synchronisation per forward)."""

    pinned: tuple[str, ...]
    dynamic: int


def pin_host_arguments(module: Any) -> PinReport:
    """Keep the constants that only feed host-read arguments in host memory.

    ``module`` is onnx2torch's ``torch.fx.GraphModule``, already on its device and in its
    dtype (moving or casting it afterwards moves them back).
    """
    graph = getattr(module, 'graph', None)
    if graph is None:
        return PinReport((), 0)
    host_uses: dict[str, int] = {}
    dynamic = 0
    for node in graph.nodes:
        if node.op != 'call_module':
            continue
        submodule = module.get_submodule(node.target)
        names = HOST_ARGUMENTS.get(type(submodule).__name__)
        if not names:
            continue
        try:
            bound = inspect.signature(submodule.forward).bind(*node.args, **node.kwargs)
        except TypeError:
            continue
        for name in names:
            arg = bound.arguments.get(name)
            if arg is None or not hasattr(arg, 'op'):
                continue  # absent, or a Python value: nothing read from the device
            if arg.op == 'get_attr':
                host_uses[arg.target] = host_uses.get(arg.target, 0) + 1
            else:
                dynamic += 1
    uses: dict[str, int] = {}
    for node in graph.nodes:
        if node.op == 'get_attr' and node.target in host_uses:
            uses[node.target] = uses.get(node.target, 0) + len(node.users)
    pinned = []
    for target, count in sorted(host_uses.items()):
        if uses.get(target) != count:
            continue  # also read by device work: stays where it is
        owner, _, name = target.rpartition('.')
        holder = module.get_submodule(owner) if owner else module
        buffer = holder._buffers.get(name)
        if buffer is None:
            continue
        if buffer.device.type != 'cpu':
            holder._buffers[name] = buffer.cpu()
        pinned.append(target)
    return PinReport(tuple(pinned), dynamic)
