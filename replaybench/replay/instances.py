"""Backend instances: the same backend under several settings in one run.

``--backend LABEL=NAME`` makes an instance of the registered backend ``NAME`` called ``LABEL``
(``--backend NAME`` alone: an instance called ``NAME``); ``--param LABEL.KEY=VALUE`` sets one
option of that instance alone, on top of the options every backend of the run is given
(``with_params``: the typed ``BackendOptions`` fields, or else a key of the backend's own
options, ``BackendOptions.extra``, which the backend checks when it is made). The label names
the instance in every output (frames.csv, summary.csv, run.json, outputs.mcap's topics,
report.html, the terminal's table), with ``-`` written ``_`` as backend names are
(``replaybench.replay.config.backend_label``).

``split_param`` reads the ``TARGET.KEY=VALUE`` spelling that ``replaybench sweep`` shares (there
with several values, separated by commas).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from replaybench.errors import UsageError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from replaybench.backends.base import BackendOptions

__all__ = [
    'BackendInstance',
    'ParamSpec',
    'backend_label',
    'check_label',
    'instance_options',
    'parse_backend',
    'parse_instances',
    'split_param',
    'with_params',
]

#: ``BackendOptions`` fields a parameter sets, by the type its text is read as
FLOAT_KEYS = ('conf', 'iou')
INT_KEYS = ('threads', 'device')
PATH_KEYS = ('config', 'model')
STR_KEYS = ('model_family', 'labels', 'engine', 'precision')

_LABEL = re.compile(r'[A-Za-z0-9_-]+')
_LABEL_RULE = "letters, digits, '_' and '-' only (no '+', '=' or '.')"


def backend_label(name: str) -> str:
    """The label a backend (an instance) carries in frames.csv, summary.csv and outputs.mcap's
    topics: its name with ``-`` written ``_``."""
    return name.replace('-', '_')


@dataclass(frozen=True, slots=True)
class BackendInstance:
    """One instance of a run: its ``label`` (its name in every output), the registered
    ``backend`` it is made of and its own ``params`` (key, text) in the order given."""

    label: str
    backend: str
    params: tuple[tuple[str, str], ...] = ()


class ParamSpec(NamedTuple):
    """One ``--param TARGET.KEY=VALUE`` split: the instance (or backend) it names, the key and
    the value text (a sweep's: values separated by commas)."""

    target: str
    key: str
    value: str


def check_label(label: str, given: str) -> None:
    """UsageError unless ``label`` is a label an instance may have (``given``: the option text
    it came from, named in the error)."""
    if not _LABEL.fullmatch(label):
        what = 'an empty label' if not label else f'label {label!r}'
        msg = f'--backend {given!r}: {what}: a label is {_LABEL_RULE}'
        raise UsageError(msg)


def parse_backend(text: str) -> tuple[str, str]:
    """``--backend LABEL=NAME`` (or ``NAME``) as (label, backend name); UsageError for a
    malformed one or a label of characters a label may not hold."""
    label, eq, name = text.partition('=')
    label, name = label.strip(), name.strip()
    if not eq:
        return text, text
    if not name:
        msg = f'--backend {text!r}: no backend name after =: use --backend LABEL=NAME'
        raise UsageError(msg)
    check_label(label, text)
    return label, name


def split_param(text: str, usage: str) -> ParamSpec:
    """``TARGET.KEY=VALUE`` split at its first ``.`` and ``=``; UsageError showing ``usage``
    (the form and an example) when a part is missing."""
    spec, eq, value = text.partition('=')
    target, dot, key = spec.strip().partition('.')
    target, key = target.strip(), key.strip()
    if not (eq and dot and target and key):
        msg = f'invalid --param {text!r}: use {usage}'
        raise UsageError(msg)
    return ParamSpec(target, key, value.strip())


def parse_instances(backends: Sequence[str], params: Sequence[str] = ()) -> list[BackendInstance]:
    """The instances of ``--backend`` and ``--param`` (one value each), in ``--backend``'s
    order. UsageError in one line for two instances with the same label (also once ``-`` is
    written ``_``), a malformed option, a parameter that names no instance, one given twice or
    one of a value of the wrong type (``with_params``)."""
    order: list[tuple[str, str]] = []
    seen: dict[str, str] = {}
    for text in backends:
        label, name = parse_backend(text)
        written = backend_label(label)
        if written in seen:
            first = seen[written]
            same = f'label {label!r}' if first == label else f'labels {first!r} and {label!r}'
            msg = (
                f'two --backend instances have the {same} (written {written!r} in the outputs): '
                'give each its own, --backend LABEL=NAME'
            )
            raise UsageError(msg)
        seen[written] = label
        order.append((label, name))
    labels = [label for label, _ in order]
    mine: dict[str, list[tuple[str, str]]] = {label: [] for label in labels}
    for text in params:
        spec = split_param(text, 'LABEL.KEY=VALUE, e.g. --param int8.threads=1')
        if spec.target not in mine:
            msg = (
                f'--param {text!r}: no --backend instance is labelled {spec.target!r} '
                f'(instances: {", ".join(labels) or "none"})'
            )
            raise UsageError(msg)
        if not spec.value:
            msg = f'--param {text!r}: empty value'
            raise UsageError(msg)
        if ',' in spec.value and spec.key not in PATH_KEYS:
            msg = (
                f'--param {text!r}: one value per instance in a run (several values, '
                'separated by commas, are for replaybench sweep)'
            )
            raise UsageError(msg)
        if any(key == spec.key for key, _ in mine[spec.target]):
            msg = f'--param {spec.target}.{spec.key} is given twice'
            raise UsageError(msg)
        mine[spec.target].append((spec.key, spec.value))
    found = [BackendInstance(label, name, tuple(mine[label])) for label, name in order]
    from replaybench.backends.base import BackendOptions

    for inst in found:  # a value of the wrong type: refused now, naming the option
        with_params(BackendOptions(), inst.params, where=inst.label)
    return found


def _typed(key: str, text: str, where: str) -> Any:
    name = f'{where}.{key}' if where else key
    if key in FLOAT_KEYS:
        try:
            return float(text)
        except ValueError as err:
            msg = f'--param {name}={text!r}: expected a number'
            raise UsageError(msg) from err
    if key in INT_KEYS:
        low = 1 if key == 'threads' else 0
        if not text.isdigit() or int(text) < low:
            msg = f'--param {name}={text!r}: expected an integer >= {low}'
            raise UsageError(msg)
        return int(text)
    if key in PATH_KEYS:
        return Path(text)
    return text


def with_params(
    base: BackendOptions, params: Mapping[str, str] | Sequence[tuple[str, str]], where: str = ''
) -> BackendOptions:
    """``base`` with ``params`` applied: typed ``BackendOptions`` fields (conf, iou, threads,
    device, config, model, model_family, labels, engine, precision) or else ``extra`` keys,
    which the backend checks when it is made. UsageError (naming ``where``, the instance) for
    a value of the wrong type."""
    pairs = list(params.items()) if hasattr(params, 'items') else list(params)
    changes: dict[str, Any] = {}
    extra = dict(base.extra)
    for key, text in pairs:
        if key in (*FLOAT_KEYS, *INT_KEYS, *PATH_KEYS, *STR_KEYS):
            changes[key] = _typed(key, text, where)
        else:
            extra[key] = text
    return replace(base, extra=extra, **changes)


def instance_options(base: BackendOptions, instance: BackendInstance) -> BackendOptions:
    """The options ``instance`` is made with: ``base`` (every backend's) with its params."""
    if not instance.params:
        return base
    return with_params(base, instance.params, where=instance.label)
