"""The tracks task: tracks against the identities of the box ground truth."""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

from replaybench.tasks.base import LazyMapping, MetricSpec, TaskViews

if TYPE_CHECKING:
    from collections.abc import Mapping

    from replaybench.decode.recorded import OutputReader
    from replaybench.tasks.base import Better

__all__ = ['FRAME_COLUMNS', 'TASK', 'TracksTask']

#: frames.csv's column of a tracked backend's row: the tracker's time on the frame
FRAME_COLUMNS = ('track_ms',)


def _share(
    name: str,
    label: str,
    short: str,
    better: Better = 'higher',
    *,
    sweep: bool = False,
    main: bool = False,
    terminal_label: str | None = None,
    fmt: str = '.4f',
) -> MetricSpec:
    return MetricSpec(
        name,
        label,
        short,
        better,
        fmt=fmt,
        sweep=sweep,
        main=main,
        terminal_label=terminal_label,
    )


class TracksTask:
    """Tracks of a (backend, topic) as one sequence: HOTA (DetA, AssA, LocA), identity
    (IDF1, IDP, IDR) and CLEAR (MOTA, MOTP, ID switches, fragmentations, MT/ML as fractions
    of the truth's objects). Sequence metrics: no per-frame value, no interval."""

    name: ClassVar[str] = 'tracks'
    metrics: ClassVar[tuple[MetricSpec, ...]] = (
        _share('hota', 'HOTA', 'HOTA', sweep=True, main=True, terminal_label='HOTA'),
        _share('deta', 'DetA', 'DetA'),
        _share('assa', 'AssA', 'AssA', sweep=True),
        _share('loca', 'LocA', 'LocA'),
        _share('idf1', 'IDF1', 'IDF1', sweep=True, terminal_label='IDF1'),
        _share('idp', 'IDP', 'IDP'),
        _share('idr', 'IDR', 'IDR'),
        _share('mota', 'MOTA', 'MOTA', sweep=True, terminal_label='MOTA'),
        _share('motp', 'MOTP', 'MOTP'),
        _share('id_switches', 'ID switches', 'IDSW', 'lower', fmt='.0f'),
        _share('fragmentations', 'fragmentations', 'Frag', 'lower', fmt='.0f'),
        _share('mt', 'mostly tracked (share of objects)', 'MT'),
        _share('ml', 'mostly lost (share of objects)', 'ML', 'lower'),
        # streaming scores (replaybench.replay.streaming): each frame's truth against the
        # tracks in use at its release; timed rates and recorded outputs only
        _share('streaming_hota', 'streaming HOTA', 'stream HOTA'),
        _share('streaming_idf1', 'streaming IDF1', 'stream IDF1'),
        _share('streaming_mota', 'streaming MOTA', 'stream MOTA'),
        MetricSpec(
            'track_ms',
            'mean tracker time per frame',
            'track ms',
            'lower',
            unit='ms',
            fmt='.4g',
            gate=False,
        ),
    )
    #: the streaming metrics, each with the offline figure it is the streaming form of, and
    #: how picks are scored to them (``replaybench.tasks.tracks.streaming``)
    streaming_metrics: ClassVar[Mapping[str, str]] = {
        'streaming_hota': 'hota',
        'streaming_idf1': 'idf1',
        'streaming_mota': 'mota',
    }
    streaming: ClassVar[str] = 'replaybench.tasks.tracks.streaming:score'
    frame_columns: ClassVar[tuple[str, ...]] = FRAME_COLUMNS
    #: ``replaybench run``'s table: HOTA, IDF1 and MOTA after the memory column, where a row
    #: has them; the report shows HOTA in its Summary and the others under More figures, and
    #: each tracked row's id-switch timeline in its Tracking section
    views: ClassVar[TaskViews] = TaskViews(
        more_columns='replaybench.tasks.tracks.views:more_columns',
        section_panel='replaybench.report.tracks:track_timelines_html',
        terminal_metrics=('hota', 'idf1', 'mota'),
    )

    #: each frame's tracks kept and, against the box truth's ids, scored after the passes
    recording: ClassVar[str] = 'replaybench.tasks.tracks.recording:recording'

    #: nothing of its own: a tracked backend's detector reads the recorded boxes
    recorded_readers: ClassVar[Mapping[str, OutputReader]] = LazyMapping(
        'replaybench.tasks.tracks.recording:READERS'
    )


TASK = TracksTask()
