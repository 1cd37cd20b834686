"""GPU backends: ``cuda`` (ONNX detector via onnxruntime-gpu or PyTorch), ``tensorrt``
(onnxruntime's TensorRT provider) and ``hsv-cuda`` (the hsv detector with CuPy).

Importing this package or its backend modules imports neither torch nor CuPy; they are
imported by ``open()``, and by ``available()`` only once an NVIDIA driver is found.
See docs/gpu.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from replaybench.results.model import RunResult

__all__ = ['engine_lines']


def engine_lines(run: RunResult) -> list[str]:
    """One line per backend of a run.json that chose an engine: which engine ran and why, and
    the precision it ran in (``replaybench run`` prints them after the summary)."""
    lines = []
    for entry in run.backends:
        facts = entry.info
        if not facts.get('engine_requested'):
            continue
        why = facts.get('engine_choice') or f'--engine {facts["engine_requested"]}'
        line = f'{entry.label or entry.name}: engine {facts.get("engine")} ({why})'
        if facts.get('precision'):
            line += f', precision {facts["precision"]}'
        if facts.get('precision_note'):
            line += f' ({facts["precision_note"]})'
        lines.append(line)
    return lines
