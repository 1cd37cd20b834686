"""Cheap, honest answers to "can this GPU backend run here, and if not, why not?".

Module presence is checked with ``importlib.util.find_spec`` and the GPU with the CUDA driver
(``libcuda``) before anything heavy is imported: torch and CuPy are imported only once a GPU
is known to be there. onnxruntime (a core dependency) is imported to list its providers.

Every problem found is reported, joined by ``'; '``, so that one ``replaybench backends``
tells everything that is missing.
"""

from __future__ import annotations

import functools
import importlib.util
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.backends.base import Availability
from replaybench.backends.gpu._cuda import driver_problem
from replaybench.backends.gpu._libs import (
    CUDA_MAJOR,
    ORT_CUDA_LIBRARIES,
    TENSORRT_INSTALL,
    TENSORRT_LIBRARIES,
    TENSORRT_MAJOR,
    find_library,
    load_error,
    load_libraries,
    other_tensorrt,
    version_of,
)
from replaybench.errors import BackendUnavailableError

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    'GPU_EXTRA',
    'check_placement',
    'check_session_providers',
    'cuda_availability',
    'cupy_problem',
    'ep_node_counts',
    'hsv_cuda_availability',
    'module_missing',
    'ort_cuda_library_problem',
    'ort_provider_library',
    'ort_provider_load_problem',
    'ort_provider_problem',
    'tensorrt_availability',
    'tensorrt_library_version',
    'tensorrt_problem',
    'torch_problem',
]

GPU_EXTRA = "pip install 'replaybench[gpu]'"
_DOCS = 'see docs/gpu.md'


def module_missing(name: str) -> bool:
    """Whether ``name`` cannot be imported (checked without importing it)."""
    try:
        return importlib.util.find_spec(name) is None
    except (ImportError, ValueError):
        return True


def ort_provider_problem(provider: str) -> str | None:
    """Why onnxruntime lacks ``provider``, or None when its build has it.

    The list only says what the build contains: onnxruntime-gpu lists the CUDA and TensorRT
    providers even without a GPU, so a session's own providers must be checked after creating
    it (``check_session_providers``).
    """
    if module_missing('onnxruntime'):
        return 'onnxruntime is not installed: install onnxruntime-gpu (see docs/gpu.md)'
    try:
        import onnxruntime as ort

        available = list(ort.get_available_providers())
        version = str(getattr(ort, '__version__', '?'))
    except Exception as exc:  # noqa: BLE001  a broken install is a reason, not a crash
        return f'onnxruntime cannot be imported: {type(exc).__name__}: {exc}'
    if provider not in available:
        return (
            f'onnxruntime {version} has no {provider}: install onnxruntime-gpu in place of '
            f'onnxruntime ({_DOCS})'
        )
    return None


def torch_problem(device: int | None = None) -> str | None:
    """Why torch cannot use CUDA (device ``device``), or None. Imports torch when installed."""
    if module_missing('torch'):
        return f'torch is not installed: {GPU_EXTRA}'
    try:
        torch = importlib.import_module('torch')
    except Exception as exc:  # noqa: BLE001  a broken install is a reason, not a crash
        return f'torch cannot be imported: {type(exc).__name__}: {exc}'
    if torch.version.cuda is None:
        return f'torch {torch.__version__} is a CPU-only build: install a CUDA build ({_DOCS})'
    if not torch.cuda.is_available():
        return f'torch {torch.__version__} cannot use CUDA (torch.cuda.is_available() is False)'
    count = torch.cuda.device_count()
    if device is not None and not 0 <= device < count:
        return f'torch sees no GPU with index {device} ({count} visible)'
    return None


def cupy_problem(device: int | None = None) -> str | None:
    """Why CuPy cannot use the GPU, or None. Imports CuPy when installed."""
    if module_missing('cupy'):
        return f'cupy not installed: {GPU_EXTRA}'
    try:
        cupy = importlib.import_module('cupy')
        count = int(cupy.cuda.runtime.getDeviceCount())
    except Exception as exc:  # noqa: BLE001  missing CUDA runtime libraries and the like
        return f'cupy cannot use CUDA: {type(exc).__name__}: {exc}'
    if device is not None and not 0 <= device < count:
        return f'cupy sees no GPU with index {device} ({count} visible)'
    return None


@functools.cache
def tensorrt_problem() -> str | None:
    """Why onnxruntime's TensorRT provider cannot load TensorRT, or None when it can.

    The provider links exactly ``libnvinfer.so.10`` and ``libnvonnxparser.so.10`` (TensorRT
    10.x): both must load, by name or from the ``tensorrt-cu13`` wheels (``_libs``), and
    libnvinfer must report a 10.x version. A TensorRT of another major is named, not taken.
    """
    libraries, missing = load_libraries(TENSORRT_LIBRARIES)
    if missing:
        found = [lib.name for lib in libraries if lib.found]
        others = [
            f'{name} (TensorRT {version or "?"})'
            for name, version in other_tensorrt()
            if version is None or not version.startswith(f'{TENSORRT_MAJOR}.')
        ]
        have = f'; found {", ".join(found)}' if found else ''
        if others:
            have += f'; found {", ".join(others)}, which the provider does not load'
        return (
            f'TensorRT {TENSORRT_MAJOR} libraries not found: {", ".join(missing)} (onnxruntime-gpu'
            f"'s TensorRT provider links {' and '.join(TENSORRT_LIBRARIES)}){have}: "
            f'{TENSORRT_INSTALL} ({_DOCS})'
        )
    version = version_of(libraries[0])
    if version is not None and not version.startswith(f'{TENSORRT_MAJOR}.'):
        return (
            f'{libraries[0].name} reports TensorRT {version}; the provider needs '
            f'{TENSORRT_MAJOR}.x: {TENSORRT_INSTALL} ({_DOCS})'
        )
    return None


def tensorrt_library_version() -> str | None:
    """TensorRT's version as libnvinfer reports it, None when it does not load."""
    library = find_library(TENSORRT_LIBRARIES[0])
    return version_of(library) if library.found else None


def ort_cuda_library_problem() -> str | None:
    """Why onnxruntime-gpu's CUDA provider would miss a library it links, or None.

    Loading them here (by name, else from the ``nvidia`` wheels) also makes them available to
    the provider, which then loads from the process what it would not find on the path.
    """
    _, missing = load_libraries(ORT_CUDA_LIBRARIES)
    if not missing:
        return None
    return (
        f"onnxruntime-gpu's CUDA provider links {', '.join(missing)}, not found (CUDA "
        f"{CUDA_MAJOR} / cuDNN 9): pip install 'onnxruntime-gpu[cuda,cudnn]' ({_DOCS})"
    )


#: onnxruntime's shared library of each GPU provider (``onnxruntime/capi``).
_PROVIDER_LIBRARIES = {
    'CUDAExecutionProvider': 'onnxruntime_providers_cuda',
    'TensorrtExecutionProvider': 'onnxruntime_providers_tensorrt',
}


def ort_provider_library(provider: str) -> Path | None:
    """Where onnxruntime keeps ``provider``'s shared library (``capi/libonnxruntime_providers_
    cuda.so``), found without importing onnxruntime; None for another provider or no
    onnxruntime."""
    stem = _PROVIDER_LIBRARIES.get(provider)
    if stem is None:
        return None
    try:
        spec = importlib.util.find_spec('onnxruntime')
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    name = f'{stem}.dll' if sys.platform == 'win32' else f'lib{stem}.so'
    return Path(next(iter(spec.submodule_search_locations))) / 'capi' / name


def ort_provider_load_problem(provider: str) -> str | None:
    """Why onnxruntime cannot load ``provider`` (its shared library or one that it links), in
    the loader's own words, or None when it loads.

    With ``session.disable_cpu_ep_fallback`` a provider that does not load leaves every node to
    the CPU, and session creation fails saying only that nodes were "assigned to the default
    CPU EP": this names what is missing instead. The CUDA / cuDNN libraries the CUDA provider
    links are checked first (``ort_cuda_library_problem``: every one missing is named), then the
    provider's own library is loaded, which names the first library the loader could not find.
    """
    libraries = ort_cuda_library_problem()
    if libraries is not None:
        return libraries
    path = ort_provider_library(provider)
    if path is None:
        return None
    if not path.is_file():
        return (
            f'onnxruntime has no {path.name} (not an onnxruntime-gpu build): install '
            f'onnxruntime-gpu in place of onnxruntime ({_DOCS})'
        )
    error = load_error(str(path))
    if error is not None:
        return f'{path.name} does not load: {error} ({_DOCS})'
    return None


def _join(problems: Sequence[str | None]) -> Availability:
    found = [p for p in problems if p]
    return Availability(ok=not found, reason='; '.join(found))


def cuda_availability() -> Availability:
    """The ``cuda`` backend: a GPU, torch with CUDA, and ORT's CUDA provider or onnx2torch."""
    driver = driver_problem()
    torch_missing = module_missing('torch')
    ort = ort_provider_problem('CUDAExecutionProvider')
    engine = None
    if ort is not None and module_missing('onnx2torch'):
        engine = (
            f'no inference engine: {ort}; or, for --engine torch, onnx2torch is not installed: '
            f'{GPU_EXTRA}'
        )
    problems = [driver]
    if torch_missing:
        problems.append(f'torch is not installed (GPU pre/post-processing needs it): {GPU_EXTRA}')
    problems.append(engine)
    if driver is None and not torch_missing:
        problems.append(torch_problem())
    return _join(problems)


def tensorrt_availability() -> Availability:
    """The ``tensorrt`` backend: a GPU, torch with CUDA, ORT's TensorRT provider, libnvinfer."""
    driver = driver_problem()
    problems = [driver, ort_provider_problem('TensorrtExecutionProvider')]
    problems.append(tensorrt_problem())
    if module_missing('torch'):
        problems.append(f'torch is not installed (GPU pre/post-processing needs it): {GPU_EXTRA}')
    elif driver is None:
        problems.append(torch_problem())
    return _join(problems)


def hsv_cuda_availability() -> Availability:
    """The ``hsv-cuda`` backend: a GPU and CuPy."""
    driver = driver_problem()
    if module_missing('cupy'):
        return _join([driver, f'cupy not installed: {GPU_EXTRA}'])
    return _join([driver, cupy_problem() if driver is None else None])


def check_session_providers(session: Any, wanted: str) -> list[str]:
    """The session's providers; ``BackendUnavailableError`` unless ``wanted`` is the first.

    onnxruntime drops a provider it cannot load (no GPU, missing CUDA / cuDNN / TensorRT
    libraries) with only a warning and runs on the next one, the CPU at the end: what the
    session reports is the only honest check.
    """
    providers = [str(p) for p in session.get_providers()]
    if not providers or providers[0] != wanted:
        shown = ', '.join(providers) or 'none'
        msg = (
            f'onnxruntime did not enable {wanted} (the session runs on: {shown}); '
            f'the GPU, the driver or the CUDA/cuDNN{"/TensorRT" if "Tensorrt" in wanted else ""} '
            f'libraries it needs are missing or unusable ({_DOCS}); refusing to run on the CPU'
        )
        raise BackendUnavailableError(msg)
    return providers


def ep_node_counts(session: Any) -> dict[str, int] | None:
    """Nodes per execution provider, as onnxruntime assigned them (None where the build cannot
    tell: ``get_provider_graph_assignment_info`` came with onnxruntime 1.24).

    The session must have been created with ``session.record_ep_graph_assignment_info`` = 1.
    A compiling provider (TensorRT) reports each fused subgraph with the nodes inside it.
    """
    get_info = getattr(session, 'get_provider_graph_assignment_info', None)
    if get_info is None:
        return None
    try:
        subgraphs = get_info()
    except Exception:  # noqa: BLE001  recording not enabled, or a build without it
        return None
    counts: dict[str, int] = {}
    for subgraph in subgraphs:
        name = str(subgraph.ep_name)
        counts[name] = counts.get(name, 0) + len(subgraph.get_nodes())
    return dict(sorted(counts.items()))


def check_placement(counts: dict[str, int] | None, wanted: str) -> None:
    """Refuse a session that places nodes on the CPU, or (TensorRT) gives TensorRT none.

    ``session.disable_cpu_ep_fallback`` already makes onnxruntime refuse CPU nodes when it
    creates the session; this reads what it actually did, and gives the reason in one line.
    """
    if counts is None:
        return
    total = sum(counts.values())
    on_cpu = counts.get('CPUExecutionProvider', 0)
    if on_cpu:
        msg = (
            f'onnxruntime placed {on_cpu} of {total} nodes on CPUExecutionProvider '
            f'(placement: {_placement_text(counts)}); refusing to run part of the model on the CPU'
        )
        raise BackendUnavailableError(msg)
    if wanted == 'TensorrtExecutionProvider' and not counts.get(wanted):
        msg = (
            f'TensorRT took none of the {total} nodes (placement: {_placement_text(counts)}): '
            'the run would measure the CUDA provider, not TensorRT; use --backend cuda for that'
        )
        raise BackendUnavailableError(msg)


def _placement_text(counts: dict[str, int]) -> str:
    return ', '.join(f'{name} {n}' for name, n in counts.items()) or 'none'
