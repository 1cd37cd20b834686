"""Text written into the HTML pages: escaped, and numbers formatted, alike on every page.

report.html, peak.html, sweep.html, comparison.html and the inline SVG charts show text from
bags (topic names, frame ids, class labels) and from the command line; ``escaped`` writes it
with its control characters as visible escapes (``replaybench.textsafe``) and its markup
characters as entities, quotes included, so that it is safe in an element or an attribute.
"""

from __future__ import annotations

import math
from html import escape

from replaybench.textsafe import visible, visible_lines

__all__ = ['escaped', 'escaped_lines', 'number_text']


def escaped(value: object) -> str:
    """HTML-escaped text, control characters shown as escapes (``replaybench.textsafe``)."""
    return escape(visible(str(value)), quote=True)


def escaped_lines(text: str) -> str:
    """``escaped`` for a ``<pre>`` block: its line feeds stay."""
    return escape(visible_lines(text), quote=True)


def number_text(value: float | None, spec: str, missing: str = '–') -> str:
    """``value`` formatted by the format spec ``spec`` (``'.2f'``, ``'.4g'``); ``missing`` for
    None or a value that is not finite."""
    if value is None or not math.isfinite(value):
        return missing
    return format(value, spec)
