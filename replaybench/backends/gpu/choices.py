"""The ``--engine`` and ``--precision`` values the GPU backends know, in a module light enough
for option checking to import before any backend loads."""

from __future__ import annotations

__all__ = ['ENGINES', 'PRECISIONS']

ENGINES = ('auto', 'ort', 'torch')
#: ``fp32``: TF32 off; ``tf32``: TF32 allowed (Ampere and newer); ``fp16``; ``int8``
#: (``tensorrt`` only: a model from ``replaybench quantize`` or a calibration bag).
PRECISIONS = ('fp32', 'tf32', 'fp16', 'int8')
