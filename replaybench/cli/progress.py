"""Progress on stderr: the run's frame bar and the fixture generator's lines."""

from __future__ import annotations

import sys
import time
from typing import TYPE_CHECKING, Any

from replaybench.cli._common import echo
from replaybench.textsafe import visible

if TYPE_CHECKING:
    from collections.abc import Callable


__all__ = ['FixtureProgress', 'RunProgress']


class RunProgress:
    """A one-line progress bar on stderr, drawn only when stderr is a terminal."""

    def __init__(self) -> None:
        self.enabled = sys.stderr.isatty()
        self.last = -1

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        pct = min(100, done * 100 // total)
        if pct == self.last and done != total:
            return
        self.last = pct
        bar = '#' * (pct // 4) + '.' * (25 - pct // 4)
        sys.stderr.write(f'\r[{bar}] {pct:3d}% {done}/{total} frames')
        if done >= total:
            sys.stderr.write('\n')
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled and self.last >= 0:
            sys.stderr.write('\n')

    def notice(self, line: str) -> None:
        """A line for a person (the hashing of a large input), on its own line of stderr."""
        if self.enabled and 0 <= self.last < 100:
            sys.stderr.write('\n')
        echo(line, err=True)


class FixtureProgress:
    """Progress of ``replaybench fixtures`` on ``stream``: on a terminal one line per bag,
    redrawn as its frames are written; elsewhere (a log, a pipe) a line every ``every_s``
    seconds while the generation lasts, none for a short one."""

    def __init__(
        self,
        stream: Any,
        *,
        every_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stream = stream
        self.terminal = bool(getattr(stream, 'isatty', lambda: False)())
        self.every_s = every_s
        self.clock = clock
        self.began = self.last_line = clock()
        self.last_draw = -1.0

    def __call__(self, name: str, done: int, total: int) -> None:
        now = self.clock()
        text = f'replaybench: writing {visible(name)}: {done}/{total} frames'
        if self.terminal:
            if done == total or now - self.last_draw >= 0.1:
                self.last_draw = now
                self.stream.write(f'\r{text}' + ('\n' if done == total else ''))
                self.stream.flush()
        elif now - self.last_line >= self.every_s:
            self.last_line = now
            self.stream.write(f'{text} ({now - self.began:.0f} s)\n')
            self.stream.flush()
