"""Class names of detection models: COCO-80, ``names`` metadata and labels files."""

from __future__ import annotations

import ast
from pathlib import Path

from replaybench.errors import BackendError

__all__ = ['COCO80', 'parse_names', 'read_labels_file', 'resolve_labels']

#: The 80 COCO detection classes in the order YOLOX, YOLOv5 and YOLOv8 number them.
COCO80: tuple[str, ...] = (
    'person', 'bicycle', 'car', 'motorcycle', 'airplane', 'bus', 'train', 'truck', 'boat',
    'traffic light', 'fire hydrant', 'stop sign', 'parking meter', 'bench', 'bird', 'cat', 'dog',
    'horse', 'sheep', 'cow', 'elephant', 'bear', 'zebra', 'giraffe', 'backpack', 'umbrella',
    'handbag', 'tie', 'suitcase', 'frisbee', 'skis', 'snowboard', 'sports ball', 'kite',
    'baseball bat', 'baseball glove', 'skateboard', 'surfboard', 'tennis racket', 'bottle',
    'wine glass', 'cup', 'fork', 'knife', 'spoon', 'bowl', 'banana', 'apple', 'sandwich',
    'orange', 'broccoli', 'carrot', 'hot dog', 'pizza', 'donut', 'cake', 'chair', 'couch',
    'potted plant', 'bed', 'dining table', 'toilet', 'tv', 'laptop', 'mouse', 'remote',
    'keyboard', 'cell phone', 'microwave', 'oven', 'toaster', 'sink', 'refrigerator', 'book',
    'clock', 'vase', 'scissors', 'teddy bear', 'hair drier', 'toothbrush',
)  # fmt: skip


def parse_names(text: str) -> tuple[str, ...]:
    """Class names from a ``names`` metadata value.

    Accepted: a comma-separated list (``red,green,blue``), a JSON / Python list
    (``["red", "green"]``) or a Python dict string as Ultralytics writes it
    (``{0: 'person', 1: 'bicycle'}``), whose integer keys must be 0..n-1.
    """
    stripped = text.strip()
    if not stripped:
        msg = 'empty class names'
        raise BackendError(msg)
    if stripped[0] in '[{(':
        try:
            value = ast.literal_eval(stripped)
        except (ValueError, SyntaxError, MemoryError, RecursionError) as err:
            msg = f'class names {_short(stripped)} are not a valid list or dict literal'
            raise BackendError(msg) from err
        return _from_literal(value, stripped)
    names = tuple(part.strip() for part in stripped.split(','))
    if any(not name for name in names):
        msg = f'class names {_short(stripped)} contain an empty name'
        raise BackendError(msg)
    return names


def _short(text: str) -> str:
    return repr(text if len(text) <= 60 else text[:57] + '...')


def _from_literal(value: object, text: str) -> tuple[str, ...]:
    if isinstance(value, dict):
        keys = list(value)
        if not all(isinstance(k, int) and not isinstance(k, bool) for k in keys):
            msg = f'class names {_short(text)}: dict keys must be class indices'
            raise BackendError(msg)
        if sorted(keys) != list(range(len(keys))):
            msg = f'class names {_short(text)}: class indices must be 0..{len(keys) - 1}'
            raise BackendError(msg)
        items = [value[k] for k in range(len(keys))]
    elif isinstance(value, list | tuple):
        items = list(value)
    else:
        msg = f'class names {_short(text)} are not a list or dict'
        raise BackendError(msg)
    if not items or not all(isinstance(item, str) and item.strip() for item in items):
        msg = f'class names {_short(text)} must be non-empty strings'
        raise BackendError(msg)
    return tuple(str(item).strip() for item in items)


def read_labels_file(path: str | Path) -> tuple[str, ...]:
    """One class name per line; blank lines and lines starting with ``#`` are ignored."""
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as exc:
        msg = f'{path}: cannot read labels file: {exc}'
        raise BackendError(msg) from exc
    names = tuple(
        line.strip()
        for line in text.splitlines()
        if line.strip() and not line.lstrip().startswith('#')
    )
    if not names:
        msg = f'{path}: labels file has no class names'
        raise BackendError(msg)
    return names


def resolve_labels(
    labels: str | None, metadata_names: str | None, num_classes: int | None
) -> tuple[tuple[str, ...], str]:
    """Class names and where they came from.

    Order: ``labels`` (``'coco'`` or a file) > the model's ``names`` metadata > COCO-80 when the
    model has exactly 80 classes > ``class0``, ``class1``, ... When ``num_classes`` is known, the
    count must match.
    """
    if labels is not None and labels.strip().lower() == 'coco':
        names, source = COCO80, 'coco'
    elif labels is not None:
        names, source = read_labels_file(labels), f'file {labels}'
    elif metadata_names is not None and metadata_names.strip():
        try:
            names = parse_names(metadata_names)
        except BackendError as exc:
            msg = f'model metadata "names": {exc}'
            raise BackendError(msg) from exc
        source = 'model metadata'
    elif num_classes == len(COCO80):
        return COCO80, 'coco (80 classes, no names in the model)'
    elif num_classes is not None:
        return tuple(f'class{i}' for i in range(num_classes)), 'generated (no names in the model)'
    else:
        return (), 'class indices (no names in the model)'
    if num_classes is not None and len(names) != num_classes:
        msg = f'{source}: {len(names)} class names but the model outputs {num_classes} classes'
        raise BackendError(msg)
    return names, source
