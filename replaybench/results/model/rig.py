"""run.json's ``rig`` section: a run that replays several camera topics of one input, summed up
per backend (``replaybench.results.rig`` builds it beside the rig rows of the summary)."""

from dataclasses import dataclass

__all__ = ['RigBackend', 'RigCamera', 'RigReport', 'WorstCamera']


@dataclass(frozen=True, slots=True)
class RigCamera:
    """One camera topic of a backend's rig and the pipeline that served it (frames.csv's
    ``pipeline``: 0 for every camera of a shared run)."""

    topic: str = ''
    pipeline: int = 0


@dataclass(frozen=True, slots=True)
class WorstCamera:
    """The camera with the highest figure of its kind among a backend's cameras, and that
    figure (a p99 latency in ms, or a drop rate, 0 to 1)."""

    topic: str = ''
    value: float = 0.0


@dataclass(frozen=True, slots=True)
class RigBackend:
    """One backend over the rig: its cameras, how many pipelines served them, its rig row's
    frames, drops and p99 (summary.csv's ``rig`` row), and its worst cameras: by p99 latency
    (None where no camera has a measured frame) and by drop rate (None where no camera
    dropped a frame)."""

    backend: str = ''
    cameras: tuple[RigCamera, ...] = ()
    pipelines: int = 1
    frames: int = 0
    dropped: int = 0
    drop_rate: float | None = None
    latency_ms_p99: float | None = None
    throughput_fps: float | None = None
    worst_p99: WorstCamera | None = None
    worst_drop_rate: WorstCamera | None = None


@dataclass(frozen=True, slots=True)
class RigReport:
    """``rig``: present where the run replays more than one camera topic of an input, with
    ``--pipelines shared`` or ``per-topic`` (``mode``); how the machine's cores were divided
    (``cores``, ``threads_per_pipeline``: ``--threads``, None for the libraries' defaults; a
    shared run has one pipeline per backend); each backend's rig."""

    mode: str = 'shared'
    cores: int = 1
    threads_per_pipeline: int | None = None
    backends: tuple[RigBackend, ...] = ()
