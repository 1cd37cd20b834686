"""peak.json (``PeakResult``): the peak sustainable rate of one backend and its trials."""

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from replaybench.results.model.common import OMIT_NONE, Environment, InputInfo, Tool

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    'PEAK_SCHEMA_VERSION',
    'PeakCameras',
    'PeakResult',
    'PeakSettings',
    'PeakStart',
    'PeakTrial',
]

#: Version of the peak.json layout.
PEAK_SCHEMA_VERSION = 1


@dataclass(frozen=True, slots=True)
class PeakSettings:
    """The options of the peak search."""

    max_drop: float = 0.05
    p99_bound_ms: float | None = None
    trial_frames: int | None = None
    warmup: int | None = None
    queue_depth: int = 1
    min_hz: float | None = None
    max_hz: float | None = None
    refine_steps: int | None = None
    confirm_trials: int | None = None
    topics: tuple[str, ...] | None = None
    threads: int | None = None


@dataclass(frozen=True, slots=True)
class PeakStart:
    """Where the search started and why (JSON key ``from`` is ``source``)."""

    hz: float | None = None
    source: str | None = field(default=None, metadata={'json': 'from'})
    probe_fps: float | None = None
    recorded_hz: float | None = None
    probe_run_dir: str | None = None


@dataclass(frozen=True, slots=True)
class PeakTrial:
    """One fixed-rate trial: frames and drops from the end of the warm-up on, its p99."""

    rate_hz: float = 0.0
    frames: int = 0
    dropped: int = 0
    drop_fraction: float = 0.0
    p99_ms: float | None = None
    ok: bool = False
    run_dir: str = ''
    attempt: int = 1
    #: ``peak --cameras``: copies of the camera set replayed (absent in a rate search's trial)
    copies: int | None = field(default=None, metadata=OMIT_NONE)


@dataclass(frozen=True, slots=True)
class PeakCameras:
    """``peak --cameras``: how many copies of the bag's camera set the backend sustains at the
    recorded rate, beside the copies one camera's service time predicts on the machine's cores."""

    #: the camera set: the bag's image topics replayed (copy 0's names)
    cameras: tuple[str, ...] = ()
    #: the rate the cameras are replayed at: the lowest recorded rate among them
    recorded_hz: float | None = None
    #: one camera's service time: the mean time to decode and detect a frame of the first
    #: camera at the max rate, alone (the run ``service_run_dir``)
    service_ms: float | None = None
    service_run_dir: str | None = None
    #: the cores the process may run on
    cores: int | None = None
    #: floor(cores / (cameras x recorded_hz x service time)): an upper bound
    predicted_copies: int | None = None
    #: the most copies that passed every one of their trials, below every failing count
    copies: int | None = None
    first_failing_copies: int | None = None
    max_copies: int | None = None


@dataclass(frozen=True, slots=True)
class PeakResult:
    """peak.json: the peak sustainable rate of one backend and every trial (docs/peak.md)."""

    schema_version: int = PEAK_SCHEMA_VERSION
    kind: str = 'peak'
    tool: Tool = Tool()
    status: str = 'complete'
    command: tuple[str, ...] = ()
    started_at: str | None = None
    finished_at: str | None = None
    wall_s: float | None = None
    backend: str = ''
    input: InputInfo = InputInfo()
    settings: PeakSettings = PeakSettings()
    start: PeakStart = PeakStart()
    peak_hz: float | None = None
    peak_confirmed: bool = False
    first_failing_hz: float | None = None
    resolution_hz: float | None = None
    limit_reached: bool = False
    warnings: tuple[str, ...] = ()
    trial_rows: tuple[PeakTrial, ...] = field(default=(), metadata={'json': 'trials'})
    environment: Environment = Environment()
    #: ``peak --cameras``: the copies of the camera set sustained (absent for a rate search)
    cameras: PeakCameras | None = field(default=None, metadata=OMIT_NONE)

    @property
    def trials(self) -> 'pd.DataFrame':
        """The trials as a pandas DataFrame (``rate_hz``, ``ok``, ...; run order)."""
        from replaybench.results.tables import trials_table

        return trials_table(self.trial_rows, PeakTrial)
