"""The colour of each backend, by index: one palette for the report's charts and for the
Foxglove annotations in outputs.mcap, so a backend looks the same in both."""

from __future__ import annotations

__all__ = ['PALETTE', 'colour']

#: Colour per backend, by index (colour-blind friendly, Okabe-Ito order first).
PALETTE: tuple[str, ...] = (
    '#0072b2',
    '#d55e00',
    '#009e73',
    '#cc79a7',
    '#e69f00',
    '#56b4e9',
    '#8c564b',
    '#7f7f7f',
    '#bcbd22',
    '#17becf',
)


def colour(index: int) -> str:
    """The palette colour (``#rrggbb``) of the ``index``-th backend; the palette repeats."""
    return PALETTE[index % len(PALETTE)]
