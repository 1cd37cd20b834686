"""Text from bags made safe to show: control characters escaped, CSV formulas defused.

Topic names, frame ids, schema names, encodings and class labels come from the recording and
may hold anything, terminal control sequences included (``ESC ] 0 ; title BEL`` sets a
terminal's window title, ``ESC [ 2 J`` clears it). Wherever replaybench shows such text - on
the terminal, in report.html and comparison.html, in frames.csv, summary.csv and
comparison.csv - these characters are written as visible escapes, as a Python string literal
writes them:

* the C0 controls U+0000-U+001F (``\\t``, ``\\n``, ``\\r``, else ``\\x1b``), DEL U+007F and
  the C1 controls U+0080-U+009F (``\\x9b``);
* the bidirectional formatting characters (U+061C, U+200E, U+200F, U+202A-U+202E,
  U+2066-U+2069), the line and paragraph separators U+2028 and U+2029, and lone surrogates
  (``\\u202e``): they reorder or break what a reader sees.

``visible`` does only that (terminal and HTML). ``escape`` also doubles backslashes, so that
``unescape`` gives the original back; CSV cells of bag text use it (``csv_text``) and, when a
cell would start with ``=``, ``+``, ``-`` or ``@`` (a formula to a spreadsheet), get a leading
apostrophe (a cell starting with an apostrophe gets one more); ``from_csv`` undoes both.
run.json keeps the true names: JSON escapes control characters itself.
"""

from __future__ import annotations

import re
from functools import lru_cache

__all__ = ['csv_text', 'escape', 'from_csv', 'unescape', 'visible', 'visible_lines']

#: Everything but C0: DEL, C1, bidirectional formatting, line / paragraph separators, surrogates.
_OTHERS = r'\x7f-\x9f\u061c\u200e\u200f\u2028\u2029\u202a-\u202e\u2066-\u2069\ud800-\udfff'
_UNSAFE = re.compile(rf'[\x00-\x1f{_OTHERS}]')
_UNSAFE_OR_BACKSLASH = re.compile(rf'[\\\x00-\x1f{_OTHERS}]')
_UNSAFE_BUT_NEWLINE = re.compile(rf'[\x00-\x09\x0b-\x1f{_OTHERS}]')
_SHORT = {'\t': '\\t', '\n': '\\n', '\r': '\\r', '\\': '\\\\'}
_ESCAPE = re.compile(r'\\(?:([\\tnr])|x([0-9a-fA-F]{2})|u([0-9a-fA-F]{4}))')
_LETTERS = {'\\': '\\', 't': '\t', 'n': '\n', 'r': '\r'}
#: First characters that make a spreadsheet read a cell as a formula (OWASP), and the guard.
_FORMULA_STARTS = ('=', '+', '-', '@', "'")
_CACHE = 4096


def _sub(match: re.Match[str]) -> str:
    char = match.group()
    short = _SHORT.get(char)
    if short is not None:
        return short
    code = ord(char)
    return f'\\x{code:02x}' if code < 0x100 else f'\\u{code:04x}'


def visible(text: str) -> str:
    """``text`` with control, bidirectional-formatting and separator characters escaped."""
    if _UNSAFE.search(text) is None:
        return text
    return _UNSAFE.sub(_sub, text)


def visible_lines(text: str) -> str:
    """``visible`` on each line of ``text``: its line feeds stay (for ``<pre>`` blocks)."""
    if _UNSAFE_BUT_NEWLINE.search(text) is None:
        return text
    return _UNSAFE_BUT_NEWLINE.sub(_sub, text)


def escape(text: str) -> str:
    """``visible(text)`` with backslashes doubled: ``unescape`` reverses it exactly."""
    if _UNSAFE_OR_BACKSLASH.search(text) is None:
        return text
    return _UNSAFE_OR_BACKSLASH.sub(_sub, text)


def _unsub(match: re.Match[str]) -> str:
    letter, byte, code = match.groups()
    if letter is not None:
        return _LETTERS[letter]
    return chr(int(byte if byte is not None else code, 16))


def unescape(text: str) -> str:
    """The text ``escape`` was given; sequences it does not write stay as they are."""
    if '\\' not in text:
        return text
    return _ESCAPE.sub(_unsub, text)


@lru_cache(maxsize=_CACHE)
def csv_text(text: str) -> str:
    """A CSV cell of bag text: ``escape``, then an apostrophe before a formula's first character.

    Only for text cells (names, labels, notes): numbers are written as they are.
    """
    cell = escape(text)
    return "'" + cell if cell.startswith(_FORMULA_STARTS) else cell


@lru_cache(maxsize=_CACHE)
def from_csv(cell: str) -> str:
    """The text ``csv_text`` was given.

    Cells written before bag text was escaped read as they are, unless they start with an
    apostrophe.
    """
    if cell.startswith("'"):
        cell = cell[1:]
    return unescape(cell)
