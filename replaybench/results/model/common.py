"""What every result file shares: the program that wrote it, the inputs and the machine.

Also the field metadata the other modules of ``replaybench.results.model`` mark their fields
with (``replaybench.results.io`` reads it): ``OMIT_NONE``, ``NOT_IN_FILE``.
"""

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

__all__ = [
    'NOT_IN_FILE',
    'OMIT_NONE',
    'CpuInfo',
    'Environment',
    'GpuInfo',
    'InputInfo',
    'OpenCvInfo',
    'OsInfo',
    'Packages',
    'PythonInfo',
    'Tool',
    'TopicMeta',
    'empty_mapping',
]

#: A field left out of the file when it is None (``metadata['omit_none']``).
OMIT_NONE: Mapping[str, Any] = {'omit_none': True}
#: A field that is not in the file (``metadata['json_skip']``): data the Python API carries.
NOT_IN_FILE: Mapping[str, Any] = {'json_skip': True}


def empty_mapping() -> dict[str, Any]:
    """The default of a mapping field: a new empty dict."""
    return {}


@dataclass(frozen=True, slots=True)
class Tool:
    """The program that wrote the file."""

    name: str = 'replaybench'
    version: str = ''


@dataclass(frozen=True, slots=True)
class TopicMeta:
    """An image topic of an input, as probed."""

    name: str = ''
    msgtype: str | None = None
    encoding: str | None = None
    width: int | None = None
    height: int | None = None
    count: int | None = None
    is_depth: bool = False
    camera_info_topic: str | None = None


@dataclass(frozen=True, slots=True)
class InputInfo:
    """One BAG argument: where it is, what it holds, and what reading it ran into."""

    index: int = 0
    path: str = ''
    format: str | None = None
    size_bytes: int | None = None
    sha256: str | None = None
    truncated: bool = False
    warnings: tuple[str, ...] = ()
    ground_truth_frames: int = 0
    topics: tuple[TopicMeta, ...] = ()


@dataclass(frozen=True, slots=True)
class CpuInfo:
    """The CPU; ``governor`` is None where it cannot be read."""

    model: str | None = None
    logical_cores: int | None = None
    usable_cores: int | None = None
    machine: str | None = None
    governor: str | None = None


@dataclass(frozen=True, slots=True)
class OsInfo:
    """``platform``'s view of the operating system."""

    system: str | None = None
    release: str | None = None
    version: str | None = None
    platform: str | None = None


@dataclass(frozen=True, slots=True)
class PythonInfo:
    """The interpreter that ran."""

    version: str | None = None
    implementation: str | None = None
    executable: str | None = None


@dataclass(frozen=True, slots=True)
class OpenCvInfo:
    """OpenCV's version and its thread count during the run."""

    version: str | None = None
    threads: int | None = None


@dataclass(frozen=True, slots=True)
class Packages:
    """Versions of the libraries that shape the measurements (None when not installed)."""

    replaybench: str | None = None
    numpy: str | None = None
    onnxruntime: str | None = None
    mcap: str | None = None
    rosbags: str | None = None
    opencv: OpenCvInfo = OpenCvInfo()


@dataclass(frozen=True, slots=True)
class GpuInfo:
    """One GPU as ``nvidia-smi`` lists it."""

    name: str | None = None
    driver_version: str | None = None
    memory_total: str | None = None


@dataclass(frozen=True, slots=True)
class Environment:
    """The machine a run (or a peak search) was measured on."""

    hostname: str | None = None
    cpu: CpuInfo = CpuInfo()
    memory_total_bytes: int | None = None
    os: OsInfo = OsInfo()
    python: PythonInfo = PythonInfo()
    packages: Packages = Packages()
    load_average: tuple[float, ...] | None = None
    gpus: tuple[GpuInfo, ...] = ()
