"""Backend registry: built-in backends plus third-party ones found through entry points.

Built-in backends are named by ``'module:Class'`` strings and imported only when asked for.
Third-party packages register a backend class in the ``replaybench.backends`` entry point
group; the entry point's name is the backend name. A broken entry point is listed by
``backend_table`` as unavailable with the reason; it never breaks the other backends.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, NamedTuple, cast

from replaybench._entrypoints import PLUGIN_NAME, sorted_entry_points
from replaybench.backends.base import Availability, Backend, BackendOptions
from replaybench.errors import BackendUnavailableError, UsageError

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

__all__ = [
    'BUILTIN_BACKENDS',
    'ENTRY_POINT_GROUP',
    'Availability',
    'Backend',
    'BackendOptions',
    'BackendStatus',
    'backend_names',
    'backend_table',
    'get_backend',
]

ENTRY_POINT_GROUP = 'replaybench.backends'

#: Built-in backends, name -> ``'module:Class'``; imported on first use.
BUILTIN_BACKENDS: dict[str, str] = {
    'null': 'replaybench.backends.null:NullBackend',
    'hsv': 'replaybench.backends.hsv:HsvBackend',
    'onnx-cpu': 'replaybench.backends.onnx_cpu:OnnxCpuBackend',
    'recorded': 'replaybench.backends.recorded:RecordedBackend',
    'busy': 'replaybench.backends.busywait:BusyBackend',
    'cuda': 'replaybench.backends.gpu.cuda:CudaBackend',
    'tensorrt': 'replaybench.backends.gpu.tensorrt:TensorrtBackend',
    'hsv-cuda': 'replaybench.backends.gpu.hsv_cuda:HsvCudaBackend',
    'hsv-seg': 'replaybench.backends.hsv_seg:HsvSegBackend',
    'onnx-seg': 'replaybench.backends.onnx_seg:OnnxSegBackend',
    'onnx-stereo': 'replaybench.backends.onnx_stereo:OnnxStereoBackend',
    'cuda-stereo': 'replaybench.backends.gpu.cuda_stereo:CudaStereoBackend',
    'tensorrt-stereo': 'replaybench.backends.gpu.tensorrt_stereo:TensorrtStereoBackend',
    'apriltag': 'replaybench.backends.apriltag:AprilTagBackend',
    'aruco': 'replaybench.backends.aruco:ArucoBackend',
    'sgbm': 'replaybench.backends.sgbm:SgbmBackend',
    'bm': 'replaybench.backends.bm:BmBackend',
}

_REQUIRED_MEMBERS = ('name', 'description', 'available', 'open', 'detect', 'info', 'close')


class BackendStatus(NamedTuple):
    """One row of ``replaybench backends``."""

    name: str
    description: str
    availability: Availability
    origin: str


def _entry_points() -> list[EntryPoint]:
    """Entry points of the backend group, in a stable order (name, then target)."""
    return sorted_entry_points(ENTRY_POINT_GROUP)


def _origin(ep: EntryPoint) -> str:
    dist = getattr(ep, 'dist', None)
    if dist is not None:
        return f'entry point {ep.value} ({dist.name} {dist.version})'
    return f'entry point {ep.value}'


def _plugins() -> tuple[dict[str, EntryPoint], list[tuple[EntryPoint, str]]]:
    """Usable third-party entry points by name, and the rejected ones with the reason."""
    usable: dict[str, EntryPoint] = {}
    rejected: list[tuple[EntryPoint, str]] = []
    for ep in _entry_points():
        if ep.name in BUILTIN_BACKENDS:
            rejected.append((ep, f'name {ep.name!r} is taken by a built-in backend; ignored'))
        elif not PLUGIN_NAME.match(ep.name):
            rejected.append((ep, f'invalid backend name {ep.name!r} (letters, digits, _ and -)'))
        elif ep.name in usable:
            other = usable[ep.name].value
            rejected.append((ep, f'name {ep.name!r} is already registered by {other}; ignored'))
        else:
            usable[ep.name] = ep
    return usable, rejected


def backend_names() -> list[str]:
    """Names of all usable backends: built-ins first, then third-party ones sorted."""
    return [*BUILTIN_BACKENDS, *sorted(_plugins()[0])]


def _check_class(name: str, obj: object, target: str) -> type[Backend]:
    if not isinstance(obj, type):
        msg = f'backend {name!r}: {target} is not a class'
        raise BackendUnavailableError(msg)
    missing = [member for member in _REQUIRED_MEMBERS if not hasattr(obj, member)]
    if missing:
        msg = f'backend {name!r}: {target} is not a backend class (missing {", ".join(missing)})'
        raise BackendUnavailableError(msg)
    declared = getattr(obj, 'name', None)
    if declared != name:
        msg = f'backend {name!r}: {target} declares name {declared!r}; it must equal {name!r}'
        raise BackendUnavailableError(msg)
    return cast('type[Backend]', obj)


def _load_builtin(name: str) -> type[Backend]:
    target = BUILTIN_BACKENDS[name]
    module_name, _, attr = target.partition(':')
    try:
        obj = getattr(importlib.import_module(module_name), attr)
    except Exception as exc:  # any import failure makes the backend unavailable
        msg = f'backend {name!r}: cannot import {target}: {type(exc).__name__}: {exc}'
        raise BackendUnavailableError(msg) from exc
    return _check_class(name, obj, target)


def _load_entry_point(ep: EntryPoint) -> type[Backend]:
    try:
        obj = ep.load()
    except Exception as exc:  # a broken plugin must not break the others
        msg = f'backend {ep.name!r}: cannot load {ep.value}: {type(exc).__name__}: {exc}'
        raise BackendUnavailableError(msg) from exc
    return _check_class(ep.name, obj, ep.value)


def get_backend(name: str) -> type[Backend]:
    """The backend class registered as ``name``.

    ``DETECTOR+TRACKER`` (``hsv+sort``) is a tracker over a box backend
    (``replaybench.backends.tracked``).

    Raises ``UsageError`` naming the known backends when ``name`` is unknown, and
    ``BackendUnavailableError`` when its module or entry point cannot be loaded.
    """
    if name in BUILTIN_BACKENDS:
        return _load_builtin(name)
    if '+' in name:  # DETECTOR+TRACKER: a tracker over a box backend
        from replaybench.backends.tracked import split_name, tracked_class

        detector, tracker = cast('tuple[str, str]', split_name(name))
        return tracked_class(name, get_backend(detector), tracker)
    usable, _ = _plugins()
    if name in usable:
        return _load_entry_point(usable[name])
    known = ', '.join([*BUILTIN_BACKENDS, *sorted(usable)])
    msg = f'unknown backend {name!r}; known backends: {known}'
    raise UsageError(msg)


def _status(name: str, origin: str, load: type[Backend] | Exception) -> BackendStatus:
    if isinstance(load, Exception):
        return BackendStatus(name, '', Availability(ok=False, reason=str(load)), origin)
    cls = load
    description = str(getattr(cls, 'description', ''))
    try:
        availability = cls.available()
        if not isinstance(availability, Availability):
            ok, reason = availability
            availability = Availability(ok=bool(ok), reason=str(reason))
    except Exception as exc:  # noqa: BLE001  report, do not crash the listing
        reason = f'available() failed: {type(exc).__name__}: {exc}'
        availability = Availability(ok=False, reason=reason)
    return BackendStatus(name, description, availability, origin)


def backend_table() -> list[BackendStatus]:
    """Every backend with its description, availability on this machine and origin.

    Built-ins come first, then entry points sorted by name. Entry points that cannot be
    loaded, or whose name is invalid or already taken, are listed as unavailable.
    """
    rows: list[BackendStatus] = []
    for name in BUILTIN_BACKENDS:
        try:
            load: type[Backend] | Exception = _load_builtin(name)
        except BackendUnavailableError as exc:
            load = exc
        rows.append(_status(name, 'built-in', load))
    usable, rejected = _plugins()
    plugin_rows: list[BackendStatus] = []
    for name, ep in usable.items():
        try:
            load = _load_entry_point(ep)
        except BackendUnavailableError as exc:
            load = exc
        plugin_rows.append(_status(name, _origin(ep), load))
    for ep, reason in rejected:
        unavailable = Availability(ok=False, reason=reason)
        plugin_rows.append(BackendStatus(ep.name, '', unavailable, _origin(ep)))
    plugin_rows.sort(key=lambda row: (row.name, row.origin))
    return rows + plugin_rows
