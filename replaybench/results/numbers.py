"""Numbers read from results: a value of run.json, a summary row or a resource summary as a float.

Results hold numbers that may be missing (None), not finite (NaN from an empty series) or of
another type altogether (a hand-edited run.json): ``finite_number`` reads each as a float or
None, so the report, the comparison and the intervals treat them alike.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ['finite_number']


def finite_number(value: Any) -> float | None:
    """``value`` as a float when it is a finite int or float (a bool is not one); else None."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    number = float(value)
    return number if math.isfinite(number) else None
