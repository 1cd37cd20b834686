"""The exact shared libraries the GPU engines link, found and loaded the way they load them.

onnxruntime-gpu 1.31's CUDA provider links ``libcudart.so.13``, ``libcublas.so.13``,
``libcublasLt.so.13`` and ``libcudnn.so.9``; its TensorRT provider ``libnvinfer.so.10`` and
``libnvonnxparser.so.10``. A library of another major (``libnvinfer.so.11``, CUDA 12's
``libcudart.so.12``) does not satisfy them, so only these names count.

A library is found when the dynamic loader loads it by name, or when a pip wheel holds it
(``site-packages/nvidia/*/lib``, ``tensorrt_libs``): loading it there by its full path puts it in
the process, where the providers' own ``dlopen`` of the same name then finds it.

``_dlopen`` is the one place that touches the loader (tests replace it).
"""

from __future__ import annotations

import ctypes
import importlib.util
import sys
from pathlib import Path
from typing import Any, NamedTuple

__all__ = [
    'CUDA_MAJOR',
    'ORT_CUDA_LIBRARIES',
    'TENSORRT_INSTALL',
    'TENSORRT_LIBRARIES',
    'TENSORRT_MAJOR',
    'Library',
    'cudart_version',
    'cudnn_version',
    'find_library',
    'load_error',
    'load_libraries',
    'other_tensorrt',
    'tensorrt_version',
    'version_of',
]

#: The CUDA major of every package of the ``gpu`` extra.
CUDA_MAJOR = 13
#: The TensorRT major onnxruntime-gpu's TensorRT provider links.
TENSORRT_MAJOR = 10
TENSORRT_INSTALL = "pip install 'tensorrt-cu13>=10.13,<11'"

if sys.platform == 'win32':
    ORT_CUDA_LIBRARIES: tuple[str, ...] = (
        'cudart64_13.dll',
        'cublasLt64_13.dll',
        'cublas64_13.dll',
        'cudnn64_9.dll',
    )
    TENSORRT_LIBRARIES: tuple[str, ...] = ('nvinfer_10.dll', 'nvonnxparser_10.dll')
    _OTHER_TENSORRT = ('nvinfer.dll', 'nvinfer_11.dll', 'nvinfer_8.dll')
else:
    #: What onnxruntime-gpu's CUDA provider links, in load order (cuBLAS needs cuBLASLt).
    ORT_CUDA_LIBRARIES = (
        'libcudart.so.13',
        'libcublasLt.so.13',
        'libcublas.so.13',
        'libcudnn.so.9',
    )
    #: What onnxruntime-gpu's TensorRT provider links.
    TENSORRT_LIBRARIES = ('libnvinfer.so.10', 'libnvonnxparser.so.10')
    #: Other TensorRT builds worth naming when the right one is missing.
    _OTHER_TENSORRT = ('libnvinfer.so', 'libnvinfer.so.11', 'libnvinfer.so.8')

#: Wheels that hold the libraries: the NVIDIA namespace package and TensorRT's library wheels.
_WHEEL_MODULES = ('nvidia', 'tensorrt_libs', 'tensorrt_cu13_libs')


class Library(NamedTuple):
    """One library looked for: ``where`` is ``loader`` (by name), a file path, or '' (missing)."""

    name: str
    where: str
    handle: Any = None

    @property
    def found(self) -> bool:
        return bool(self.where)


def _dlopen(name: str) -> Any:
    """Load a shared library by name or path (``OSError`` when it cannot be loaded)."""
    mode = getattr(ctypes, 'RTLD_GLOBAL', 0)
    return ctypes.CDLL(name, mode=mode)


def load_error(path: str) -> str | None:
    """The loader's message when the library at ``path`` (or one it links) does not load,
    None when it loads."""
    try:
        _dlopen(path)
    except OSError as exc:
        return str(exc)
    return None


def _wheel_folders() -> list[Path]:
    """Folders of the installed library wheels, found without importing them."""
    folders: list[Path] = []
    for module in _WHEEL_MODULES:
        try:
            spec = importlib.util.find_spec(module)
        except (ImportError, ValueError):
            continue
        if spec is not None:
            folders.extend(Path(p) for p in spec.submodule_search_locations or [])
    return folders


def _in_wheels(name: str) -> list[Path]:
    found: list[Path] = []
    for folder in _wheel_folders():
        for pattern in (name, f'lib/{name}', f'*/lib/{name}', f'*/bin/{name}', f'*/bin/*/{name}'):
            found.extend(sorted(folder.glob(pattern)))
    return found


def find_library(name: str) -> Library:
    """Load ``name`` by name, else from a wheel that holds it; ``Library.where`` says which."""
    try:
        return Library(name, 'loader', _dlopen(name))
    except OSError:
        pass
    for path in _in_wheels(name):
        try:
            return Library(name, str(path), _dlopen(str(path)))
        except OSError:
            continue
    return Library(name, '')


def load_libraries(names: tuple[str, ...]) -> tuple[list[Library], list[str]]:
    """Every library of ``names`` (in order), and the names of those missing."""
    libraries = [find_library(name) for name in names]
    return libraries, [lib.name for lib in libraries if not lib.found]


def _call_int(handle: Any, function: str, restype: Any = ctypes.c_size_t) -> int | None:
    try:
        fn = getattr(handle, function)
    except AttributeError:
        return None
    fn.restype = restype
    try:
        return int(fn())
    except (OSError, ValueError, TypeError):
        return None


def tensorrt_version(handle: Any) -> str | None:
    """``getInferLibVersion`` of a loaded libnvinfer: 10.x encodes ``major*10000 + minor*100
    + patch`` (101300 = 10.13.0), 8.x ``major*1000 + minor*100 + patch`` (8601 = 8.6.1)."""
    value = _call_int(handle, 'getInferLibVersion', ctypes.c_int32)
    if value is None or value <= 0:
        return None
    if value >= 10000:
        return f'{value // 10000}.{value // 100 % 100}.{value % 100}'
    return f'{value // 1000}.{value // 100 % 10}.{value % 100}'


def cudnn_version(handle: Any) -> str | None:
    """``cudnnGetVersion``: 9.x encodes ``major*10000 + minor*100 + patch`` (90100 = 9.1.0)."""
    value = _call_int(handle, 'cudnnGetVersion')
    if value is None or value <= 0:
        return None
    if value >= 10000:
        return f'{value // 10000}.{value // 100 % 100}.{value % 100}'
    return f'{value // 1000}.{value // 100 % 10}.{value % 100}'


def cudart_version(handle: Any) -> str | None:
    """``cudaRuntimeGetVersion`` of a loaded libcudart (13000 = 13.0)."""
    try:
        fn = handle.cudaRuntimeGetVersion
    except AttributeError:
        return None
    value = ctypes.c_int(0)
    try:
        code = int(fn(ctypes.byref(value)))
    except (OSError, ValueError, TypeError):
        return None
    if code != 0 or value.value <= 0:
        return None
    return f'{value.value // 1000}.{value.value % 1000 // 10}'


def version_of(library: Library) -> str | None:
    """The version a loaded library reports (TensorRT, cuDNN, the CUDA runtime), else None."""
    if library.handle is None:
        return None
    if 'nvinfer' in library.name:
        return tensorrt_version(library.handle)
    if 'cudnn' in library.name:
        return cudnn_version(library.handle)
    if 'cudart' in library.name:
        return cudart_version(library.handle)
    return None


def other_tensorrt() -> list[tuple[str, str | None]]:
    """TensorRT builds of another major that load here: (name, version)."""
    found = []
    for name in _OTHER_TENSORRT:
        library = find_library(name)
        if library.found:
            found.append((name, tensorrt_version(library.handle)))
    return found
