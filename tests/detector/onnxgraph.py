"""Tiny ONNX models written straight in the protobuf wire format (no ``onnx`` package).

Only what the tests need: a graph with one float image input and constant outputs (each a
``Constant`` node), optionally with the input folded into the outputs (``+ 0 * max(input)``)
so the input is really read, plus ``metadata_props``. onnxruntime loads the result as any
exported model.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    import numpy.typing as npt

__all__ = ['Output', 'write_model']

# TensorProto.DataType
_DTYPES = {
    np.dtype(np.float32): 1,
    np.dtype(np.uint8): 2,
    np.dtype(np.int32): 6,
    np.dtype(np.int64): 7,
    np.dtype(np.float16): 10,
}
_ATTR_TENSOR = 4
_ATTR_INT = 2


def _varint(value: int) -> bytes:
    value &= (1 << 64) - 1
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _int(field: int, value: int) -> bytes:
    return _key(field, 0) + _varint(value)


def _bytes(field: int, value: bytes) -> bytes:
    return _key(field, 2) + _varint(len(value)) + value


def _str(field: int, value: str) -> bytes:
    return _bytes(field, value.encode())


def _tensor(name: str, array: npt.NDArray[np.generic]) -> bytes:
    array = np.ascontiguousarray(array)
    dims = b''.join(_int(1, d) for d in array.shape)
    return dims + _int(2, _DTYPES[array.dtype]) + _str(8, name) + _bytes(9, array.tobytes())


def _value_info(name: str, dtype: np.dtype[np.generic], shape: Sequence[int | str]) -> bytes:
    dims = b''.join(_bytes(1, _str(2, d) if isinstance(d, str) else _int(1, d)) for d in shape)
    tensor_type = _int(1, _DTYPES[dtype]) + _bytes(2, dims)
    return _str(1, name) + _bytes(2, _bytes(1, tensor_type))


def _node(
    op: str, inputs: Sequence[str], outputs: Sequence[str], attrs: Sequence[bytes] = ()
) -> bytes:
    body = b''.join(_str(1, i) for i in inputs) + b''.join(_str(2, o) for o in outputs)
    body += _str(3, f'{op}_{outputs[0]}') + _str(4, op)
    body += b''.join(_bytes(5, a) for a in attrs)
    return body


def _tensor_attr(name: str, array: npt.NDArray[np.generic]) -> bytes:
    return _str(1, name) + _bytes(5, _tensor(name, array)) + _int(20, _ATTR_TENSOR)


def _int_attr(name: str, value: int) -> bytes:
    return _str(1, name) + _int(3, value) + _int(20, _ATTR_INT)


class Output:
    """One graph output: a constant value, declared with ``shape`` (ints or symbolic names)."""

    def __init__(
        self, name: str, value: npt.NDArray[np.generic], shape: Sequence[int | str] | None = None
    ) -> None:
        self.name = name
        self.value = np.asarray(value)
        self.shape = list(self.value.shape) if shape is None else list(shape)


def write_model(
    path: Path,
    outputs: Sequence[Output],
    *,
    input_name: str = 'images',
    input_shape: Sequence[int | str] = (1, 3, 32, 32),
    input_dtype: type[np.generic] = np.float32,
    metadata: Mapping[str, str] | None = None,
    use_input: bool = True,
) -> Path:
    """Write an ONNX model (IR 8, opset 17) whose outputs are the given constants.

    ``use_input``: float outputs become ``const + 0 * ReduceMax(input)`` so that the input is
    consumed (and must have the declared shape and dtype at run time).
    """
    in_dtype = np.dtype(input_dtype)
    nodes: list[bytes] = []
    if use_input:
        nodes.append(_node('ReduceMax', [input_name], ['in_max'], [_int_attr('keepdims', 0)]))
        nodes.append(_node('Cast', ['in_max'], ['in_max32'], [_int_attr('to', 1)]))
        zero = np.zeros((), dtype=np.float32)
        nodes.append(_node('Constant', [], ['zero'], [_tensor_attr('value', zero)]))
        nodes.append(_node('Mul', ['in_max32', 'zero'], ['nothing']))
    for out in outputs:
        const = f'{out.name}_const'
        nodes.append(_node('Constant', [], [const], [_tensor_attr('value', out.value)]))
        if use_input and out.value.dtype == np.float32:
            nodes.append(_node('Add', [const, 'nothing'], [out.name]))
        else:
            nodes.append(_node('Identity', [const], [out.name]))
    graph = b''.join(_bytes(1, n) for n in nodes) + _str(2, 'test_graph')
    graph += _bytes(11, _value_info(input_name, in_dtype, input_shape))
    for out in outputs:
        graph += _bytes(12, _value_info(out.name, out.value.dtype, out.shape))
    model = _int(1, 8) + _str(2, 'replaybench-tests') + _bytes(7, graph)
    model += _bytes(8, _str(1, '') + _int(2, 17))
    for key, value in (metadata or {}).items():
        model += _bytes(14, _str(1, key) + _str(2, value))
    path.write_bytes(model)
    return path
