"""torch's TF32 switches, set so that every way of reading them agrees, and held per engine.

TF32 is process-wide in torch. torch >= 2.9 has two sets of switches: the new
``fp32_precision`` (``ieee`` / ``tf32``) of cuBLAS matmuls (``backends.cuda.matmul``) and cuDNN
convolutions and RNNs (``backends.cudnn.conv`` / ``.rnn``), and the legacy ``allow_tf32`` flags,
which torch checks against the new ones: after only ``cudnn.conv.fp32_precision = 'ieee'``,
reading ``cudnn.allow_tf32`` (as libraries and user code still do) raises, because conv, RNN and
the legacy flag disagree. ``apply_tf32`` therefore sets the legacy flags first (on torch >= 2.9
they also reset the new ones) and then the new ones of matmul, conv and RNN to the same mode, so
that both APIs read the same answer.

Engines are opened before any of them runs, and two torch engines may want different modes:
``Tf32Hold`` applies an engine's mode when it opens and again before each of its frames
(``reapply``, which sets nothing when the flags already say so), and the flags the process had
before the first hold come back when the last hold is released, whichever engine closes first.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = ['Tf32Hold', 'apply_tf32', 'save_tf32', 'set_tf32', 'tf32_mode']


class Tf32Flags(NamedTuple):
    """torch's TF32 switches as they were: the new API's modes (None: not in this torch) and
    the legacy readings (None: this torch raised on reading them, its flags disagreeing)."""

    matmul_precision: str | None
    conv_precision: str | None
    rnn_precision: str | None
    matmul_allow: bool | None
    cudnn_allow: bool | None
    float32_matmul_precision: str | None


def _has_new_api(torch: Any) -> bool:
    cudnn = torch.backends.cudnn
    return (
        hasattr(torch.backends.cuda.matmul, 'fp32_precision')
        and hasattr(cudnn, 'conv')
        and hasattr(cudnn, 'rnn')
    )


def _read(get: Callable[[], Any]) -> Any:
    try:
        return get()
    except RuntimeError:  # torch: the legacy flag and the new modes disagree
        return None


def save_tf32(torch: Any) -> Tf32Flags:
    """The TF32 switches as they are now."""
    backends = torch.backends
    new = _has_new_api(torch)
    return Tf32Flags(
        matmul_precision=str(backends.cuda.matmul.fp32_precision) if new else None,
        conv_precision=str(backends.cudnn.conv.fp32_precision) if new else None,
        rnn_precision=str(backends.cudnn.rnn.fp32_precision) if new else None,
        matmul_allow=_read(lambda: bool(backends.cuda.matmul.allow_tf32)),
        cudnn_allow=_read(lambda: bool(backends.cudnn.allow_tf32)),
        float32_matmul_precision=_read(lambda: str(torch.get_float32_matmul_precision())),
    )


def restore_tf32(torch: Any, flags: Tf32Flags) -> None:
    """Put ``flags`` (``save_tf32``) back: the legacy readings first, then the new modes."""
    backends = torch.backends
    if flags.cudnn_allow is not None:
        backends.cudnn.allow_tf32 = flags.cudnn_allow
    if flags.matmul_allow is not None:
        backends.cuda.matmul.allow_tf32 = flags.matmul_allow
    if flags.float32_matmul_precision is not None:
        torch.set_float32_matmul_precision(flags.float32_matmul_precision)
    if flags.matmul_precision is not None:
        backends.cuda.matmul.fp32_precision = flags.matmul_precision
    if flags.conv_precision is not None:
        backends.cudnn.conv.fp32_precision = flags.conv_precision
    if flags.rnn_precision is not None:
        backends.cudnn.rnn.fp32_precision = flags.rnn_precision


def tf32_mode(torch: Any) -> bool | None:
    """True / False when matmul, conv (and RNN) agree on TF32 / strict fp32, else None."""
    backends = torch.backends
    if _has_new_api(torch):
        modes = {
            backends.cuda.matmul.fp32_precision,
            backends.cudnn.conv.fp32_precision,
            backends.cudnn.rnn.fp32_precision,
        }
        return {'tf32': True, 'ieee': False}.get(modes.pop()) if len(modes) == 1 else None
    allows = {bool(backends.cuda.matmul.allow_tf32), bool(backends.cudnn.allow_tf32)}
    return allows.pop() if len(allows) == 1 else None


def apply_tf32(torch: Any, allow: bool) -> None:
    """Allow (``tf32``) or forbid (``ieee``) TF32 in matmuls, convolutions and RNNs, with the
    legacy flags saying the same."""
    backends = torch.backends
    backends.cuda.matmul.allow_tf32 = allow
    backends.cudnn.allow_tf32 = allow
    if _has_new_api(torch):
        mode = 'tf32' if allow else 'ieee'
        backends.cuda.matmul.fp32_precision = mode
        backends.cudnn.conv.fp32_precision = mode
        backends.cudnn.rnn.fp32_precision = mode


def set_tf32(torch: Any, allow: bool) -> Callable[[], None]:
    """``apply_tf32`` now; returns the undo that puts the previous switches back."""
    saved = save_tf32(torch)
    apply_tf32(torch, allow)

    def restore() -> None:
        restore_tf32(torch, saved)

    return restore


class _Holds:
    """The process's TF32 switches before the first open hold, and the holds still open."""

    lock = threading.Lock()
    count = 0
    saved: Tf32Flags | None = None


class Tf32Hold:
    """One engine's TF32 mode, from its ``open`` (``Tf32Hold(torch, allow)``) to its
    ``release``; ``reapply()`` before each of its frames."""

    def __init__(self, torch: Any, allow: bool) -> None:
        self.torch = torch
        self.allow = allow
        self._held = True
        with _Holds.lock:
            if _Holds.count == 0:
                _Holds.saved = save_tf32(torch)
            _Holds.count += 1
            apply_tf32(torch, allow)

    def reapply(self) -> None:
        """Set this engine's mode again when another engine's is in force (no-op otherwise)."""
        if tf32_mode(self.torch) is not self.allow:
            apply_tf32(self.torch, self.allow)

    def release(self) -> None:
        """This engine is closed; the last hold released puts the process's switches back.
        A second call does nothing."""
        if not self._held:
            return
        self._held = False
        with _Holds.lock:
            _Holds.count -= 1
            if _Holds.count == 0 and _Holds.saved is not None:
                restore_tf32(self.torch, _Holds.saved)
                _Holds.saved = None
