"""The tracks task's id-switch timeline of a tracked row: each truth object's frames, matched
to which track or missed, and the ID switches, as CLEAR matched them
(``replaybench.tracking.clear_matching``; ``replaybench.tasks.tracks.recording`` makes it)."""

from dataclasses import dataclass

__all__ = ['IdSwitchEvent', 'TrackLane', 'TrackSpan', 'TrackTimeline']


@dataclass(frozen=True, slots=True)
class TrackSpan:
    """Frames ``first`` to ``last`` (inclusive; indices into the row's scored sequence, from 0)
    in which one truth object is in the truth and matched to the track ``track_id`` in each,
    or missed in each (``track_id`` None)."""

    first: int = 0
    last: int = 0
    track_id: str | None = None


@dataclass(frozen=True, slots=True)
class TrackLane:
    """One truth object (its ``Detection2D.id``): its spans in frame order; the frames without
    a span are frames it is not in the truth."""

    object_id: str = ''
    spans: tuple[TrackSpan, ...] = ()


@dataclass(frozen=True, slots=True)
class IdSwitchEvent:
    """One ID switch: at ``frame`` (index into the scored sequence) the object ``object_id``
    is matched to ``to_id`` after its last match, to ``from_id``."""

    frame: int = 0
    object_id: str = ''
    from_id: str = ''
    to_id: str = ''


@dataclass(frozen=True, slots=True)
class TrackTimeline:
    """A tracked row's scored sequence (``frames`` frames, in replay order) as CLEAR matched
    it: one lane per truth object (ids in order: numbers by value, then texts) and the ID
    switches in frame order, as many as the row's ``id_switches``."""

    frames: int = 0
    lanes: tuple[TrackLane, ...] = ()
    switches: tuple[IdSwitchEvent, ...] = ()
    #: each frame's ``seq`` (frames.csv's column), in sequence order; empty where not known
    #: (a run.json written before it was kept)
    seqs: tuple[int, ...] = ()
