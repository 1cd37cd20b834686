"""Replay rates: ``max``, ``recorded``, scaled recorded (``2x``) and fixed (``30hz``)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from replaybench.errors import UsageError

__all__ = ['Rate', 'parse_rate']

_RATE = re.compile(r'^(?:(?P<x>\d+(?:\.\d*)?|\.\d+)x|(?P<hz>\d+(?:\.\d*)?|\.\d+)\s*hz)$')


@dataclass(frozen=True, slots=True)
class Rate:
    """How frames are released: all at once, at log-time spacing (scaled), or at a fixed rate."""

    mode: Literal['max', 'recorded', 'fixed']
    scale: float = 1.0
    hz: float = 0.0

    @property
    def timed(self) -> bool:
        return self.mode != 'max'

    def __str__(self) -> str:
        if self.mode == 'max':
            return 'max'
        if self.mode == 'fixed':
            return f'{self.hz:g}hz'
        return 'recorded' if self.scale == 1.0 else f'{self.scale:g}x'


def parse_rate(text: str) -> Rate:
    """Parse ``max``, ``recorded``, ``2x``, ``0.5x`` or ``30hz``."""
    value = text.strip().lower()
    if value == 'max':
        return Rate('max')
    if value == 'recorded':
        return Rate('recorded')
    match = _RATE.match(value)
    if match and match['x'] is not None and float(match['x']) > 0:
        return Rate('recorded', scale=float(match['x']))
    if match and match['hz'] is not None and float(match['hz']) > 0:
        return Rate('fixed', hz=float(match['hz']))
    msg = (
        f'invalid rate {text!r}: use max, recorded, a factor such as 2x or 0.5x, '
        'or a fixed rate such as 30hz'
    )
    raise UsageError(msg)
