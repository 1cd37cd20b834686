"""replaybench: replay camera logs through detectors and measure speed and accuracy.

The Python API (docs/api.md)::

    import replaybench as rb

    res = rb.run('bag.mcap', backends=['hsv', 'null'])
    res.summary                       # summary.csv as a pandas DataFrame

``run``, ``load_run``, ``compare``, ``peak`` and ``sweep`` and the result classes load on
first use (module ``__getattr__``): ``import replaybench`` itself imports nothing heavy.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from replaybench._version import __version__

if TYPE_CHECKING:
    from replaybench.api import compare, load_run, peak, run, sweep
    from replaybench.app.sweep import SweepResult
    from replaybench.results.model import Comparison, PeakResult, RunResult

__all__ = [
    'Comparison',
    'PeakResult',
    'RunResult',
    'SweepResult',
    '__version__',
    'compare',
    'load_run',
    'peak',
    'run',
    'sweep',
]

#: name -> the module that defines it, imported on first use
_LAZY: dict[str, str] = {
    'run': 'replaybench.api',
    'load_run': 'replaybench.api',
    'compare': 'replaybench.api',
    'peak': 'replaybench.api',
    'sweep': 'replaybench.api',
    'RunResult': 'replaybench.results.model',
    'PeakResult': 'replaybench.results.model',
    'Comparison': 'replaybench.results.model',
    'SweepResult': 'replaybench.app.sweep',
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        msg = f'module {__name__!r} has no attribute {name!r}'
        raise AttributeError(msg)
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
