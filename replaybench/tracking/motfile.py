"""MOTChallenge text files: ``frame, id, left, top, width, height, conf_or_consider, class,
visibility[, ...]``, one box a line, frames counted from 1 (MOT15 files hold ``-1`` in the
columns they lack)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from replaybench.errors import UsageError

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ['MotBox', 'read_mot_file']


@dataclass(frozen=True, slots=True)
class MotBox:
    """One line: a box of object ``id`` in frame ``frame`` (from 1), x y w h in pixels; ``conf``
    the 7th column (a tracker's confidence, or the truth's "consider" flag), ``cls`` and
    ``visibility`` the 8th and 9th (-1 where the file has none)."""

    frame: int
    id: int
    x: float
    y: float
    w: float
    h: float
    conf: float = -1.0
    cls: int = -1
    visibility: float = -1.0


def _number(text: str, path: Path, line: int, column: int) -> float:
    try:
        value = float(text)
    except ValueError:
        msg = f'{path}:{line}: column {column} is not a number: {text.strip()!r}'
        raise UsageError(msg) from None
    if not math.isfinite(value):
        msg = f'{path}:{line}: column {column} is not finite: {text.strip()!r}'
        raise UsageError(msg)
    return value


def read_mot_file(path: Path) -> list[MotBox]:
    """Every box of a MOTChallenge file, in file order. ``UsageError`` naming the line for a
    line with fewer than 6 columns, a value that is no number, a frame below 1 or a frame or
    id that is no integer; blank lines are skipped."""
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as err:
        msg = f'{path}: cannot read the MOT file: {err}'
        raise UsageError(msg) from err
    boxes: list[MotBox] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        cells = raw.replace(' ', '').split(',')
        if len(cells) < 6:
            msg = f'{path}:{number}: {len(cells)} columns, a MOT line has at least 6'
            raise UsageError(msg)
        values = [_number(c, path, number, i + 1) for i, c in enumerate(cells[:9])]
        frame, ident = values[0], values[1]
        if frame != int(frame) or ident != int(ident) or frame < 1:
            msg = f'{path}:{number}: frame and id must be integers, the frame from 1'
            raise UsageError(msg)
        conf, cls, visibility = [*values[6:9], -1.0, -1.0, -1.0][:3]
        x, y, w, h = values[2:6]
        boxes.append(MotBox(int(frame), int(ident), x, y, w, h, conf, int(cls), visibility))
    return boxes
