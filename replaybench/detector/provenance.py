"""The calibration provenance ``replaybench quantize`` writes into an INT8 model.

One ``metadata_props`` entry, ``replaybench.quantization``, holds a JSON object: the bag it was
calibrated on (``bag``, ``bag_sha256``, ``topics``), the frames used (``frames``: their count,
``frames_used``: per topic its ``seq`` numbers), ``method``, ``format``, ``per_channel``, the
nodes left in float (``excluded``, ``exclude_rule``), the opset upgrade (``opset_from``,
``opset_to``), the float model's sha256 (``source_sha256``) and ``replaybench`` (the version).
The ONNX backends report it in run.json (``info()['quantization']``) and on the terminal
(``quantization_line``).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Mapping

__all__ = ['PROVENANCE_KEY', 'provenance', 'quantization_line']

#: The metadata key of the provenance.
PROVENANCE_KEY = 'replaybench.quantization'


def provenance(metadata: Mapping[str, str]) -> dict[str, Any] | None:
    """The provenance a model's metadata holds; None when it holds none. A value that is no
    JSON object is kept as ``{'unreadable': text}`` rather than dropped."""
    text = metadata.get(PROVENANCE_KEY)
    if text is None:
        return None
    try:
        value = json.loads(text)
    except ValueError:
        return {'unreadable': text[:200]}
    return value if isinstance(value, dict) else {'unreadable': text[:200]}


def quantization_line(backend: str, facts: Mapping[str, Any]) -> str | None:
    """One terminal line on a backend's INT8 model, from its ``info()``; None for a float one."""
    found = facts.get('quantization')
    if not isinstance(found, dict):
        return None
    if 'unreadable' in found:
        return f'{backend}: INT8 model with unreadable {PROVENANCE_KEY} metadata'
    sha = str(found.get('bag_sha256') or '?')[:12]
    excluded = found.get('excluded') or []
    floats = f'{len(excluded)} node(s) in float' if excluded else 'every node quantised'
    return (
        f'{backend}: INT8 model calibrated by replaybench {found.get("replaybench", "?")} on '
        f'{found.get("bag", "?")} (sha256 {sha}), {found.get("frames", "?")} frame(s), '
        f'{found.get("method", "?")}, {found.get("format", "?")}, {floats}'
    )
