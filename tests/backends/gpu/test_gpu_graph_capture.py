"""CUDA-graph capture of the torch engine: on a side stream made on the input's device and passed
to ``torch.cuda.graph`` (its default is a process-wide stream made on whichever device was
current first), and not tried at all when the forward synchronises with the host, where
capture fails anyway.

torch's CUDA calls are stood in for at ``torch.cuda`` (streams, graphs, the sync debug mode);
the module is a plain callable.
"""

from __future__ import annotations

import contextlib
import types
import warnings
from typing import Any

from replaybench.backends.gpu.cuda import TorchEngine


class _Stream:
    def __init__(self, device: Any = None) -> None:
        self.device = device

    def wait_stream(self, other: Any) -> None:
        return None


class _CudaGraph:
    replays = 0

    def replay(self) -> None:
        type(self).replays += 1


def _torch(syncs: int) -> tuple[Any, dict[str, Any]]:
    """torch with a ``cuda`` whose sync debug mode warns ``syncs`` times per forward."""
    seen: dict[str, Any] = {'graph_stream': 'not captured', 'mode': 0}

    def set_sync_debug_mode(mode: Any) -> None:
        seen['mode'] = mode

    @contextlib.contextmanager
    def graph(_graph: Any, _pool: Any = None, stream: Any = None) -> Any:
        seen['graph_stream'] = stream
        yield

    cuda = types.SimpleNamespace(
        Stream=_Stream,
        stream=lambda s: contextlib.nullcontext(),
        current_stream=lambda device=None: _Stream(device),
        CUDAGraph=_CudaGraph,
        graph=graph,
        synchronize=lambda device=None: None,
        set_sync_debug_mode=set_sync_debug_mode,
        get_sync_debug_mode=lambda: seen['mode'],
    )
    torch = types.SimpleNamespace(cuda=cuda, inference_mode=contextlib.nullcontext)

    def module(_input: Any) -> list[str]:
        if seen['mode'] == 'warn':
            for _ in range(syncs):
                warnings.warn('called a synchronizing CUDA operation', UserWarning, stacklevel=1)
        return ['boxes']

    seen['module'] = module
    return torch, seen


def _input(index: int) -> Any:
    return types.SimpleNamespace(device=types.SimpleNamespace(type='cuda', index=index))


def test_the_graph_is_captured_on_the_side_stream_of_the_inputs_device():
    torch, seen = _torch(syncs=0)
    engine = TorchEngine(torch, seen['module'], _input(1), ['output0'], cuda_graph=True)
    assert engine.syncs == 0
    assert engine.graph_note == 'captured'
    stream = seen['graph_stream']
    assert isinstance(stream, _Stream)
    assert stream.device.index == 1
    assert engine() == {'output0': 'boxes'}


def test_a_forward_that_synchronises_is_not_captured_and_says_why():
    torch, seen = _torch(syncs=2)
    engine = TorchEngine(torch, seen['module'], _input(0), ['output0'], cuda_graph=True)
    assert engine.syncs == 2
    assert engine.graph is None
    assert seen['graph_stream'] == 'not captured'
    assert engine.graph_note == (
        'eager (the forward synchronises with the host 2 time(s), which a CUDA graph cannot '
        'capture)'
    )
    assert engine() == {'output0': 'boxes'}
