"""run.json's ``sync`` section: the synchronised frame sets of ``--sync``
(``replaybench.replay.sync`` groups them, ``replaybench.replay.pairing`` reads the stamps)."""

from collections.abc import Mapping
from dataclasses import dataclass, field

from replaybench.results.model.common import empty_mapping

__all__ = ['SyncInput', 'SyncReport', 'SyncTopic']


@dataclass(frozen=True, slots=True)
class SyncTopic:
    """One topic of an input's sets: its frames, those in a set and those in none."""

    topic: str = ''
    frames: int = 0
    paired: int = 0
    unpaired: int = 0


@dataclass(frozen=True, slots=True)
class SyncInput:
    """The sets of one input (``input``: its index in run.json's ``inputs``): how many, the
    largest spread of a set's stamps, and each topic's frames."""

    input: int = 0
    sets: int = 0
    spread_ms_max: float | None = None
    topics: tuple[SyncTopic, ...] = ()


@dataclass(frozen=True, slots=True)
class SyncReport:
    """``--sync``: the policy (``sync`` as given, ``mode`` exact or approx, ``slop_ms`` the
    largest spread of a set, null for exact), what each backend was given (by label:
    ``frames`` or ``sets``), the seconds the header stamps took to read before the first
    frame, and each input's sets."""

    sync: str = 'exact'
    mode: str = 'exact'
    slop_ms: float | None = None
    policy: str = ''
    backends: Mapping[str, str] = field(default_factory=empty_mapping)
    stamps_read_s: float | None = None
    inputs: tuple[SyncInput, ...] = ()
