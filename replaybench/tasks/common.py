"""The metrics of every task: the replay's latency and throughput, and a recording's latency."""

from __future__ import annotations

from replaybench.tasks.base import MetricSpec

__all__ = ['COMMON_METRICS']


def _recorded(name: str, label: str, short_label: str) -> MetricSpec:
    return MetricSpec(
        name, label, short_label, 'lower', kind='recorded', unit='ms', fmt='.4g', appended=False
    )


#: In table order: the replay's timings, the recorded outputs' latency
#: (``replaybench.comparison.recorded``), then a rig row's figures (a run replaying several
#: camera topics of an input: ``replaybench.results.rig``).
COMMON_METRICS: tuple[MetricSpec, ...] = (
    MetricSpec(
        'median_ms',
        'median latency',
        'median ms',
        'lower',
        kind='timing',
        unit='ms',
        fmt='.4g',
        aliases=('p50_ms',),
        appended=False,
    ),
    MetricSpec(
        'p99_ms',
        'p99 latency',
        'p99 ms',
        'lower',
        kind='timing',
        unit='ms',
        fmt='.4g',
        appended=False,
    ),
    MetricSpec(
        'mean_ms',
        'mean latency',
        'mean ms',
        'lower',
        kind='timing',
        unit='ms',
        fmt='.4g',
        appended=False,
    ),
    MetricSpec(
        'fps',
        'throughput',
        'FPS',
        'higher',
        kind='timing',
        unit='fps',
        fmt='.4g',
        aliases=('throughput_fps',),
        appended=False,
    ),
    _recorded('recorded_pipeline_ms', 'recorded median pipeline latency', 'recorded pipeline ms'),
    _recorded(
        'recorded_pipeline_p99_ms', 'recorded p99 pipeline latency', 'recorded pipeline p99 ms'
    ),
    _recorded(
        'recorded_capture_ms', 'recorded median capture-to-output latency', 'recorded capture ms'
    ),
    _recorded(
        'recorded_capture_p99_ms',
        'recorded p99 capture-to-output latency',
        'recorded capture p99 ms',
    ),
    MetricSpec(
        'rig_p99_ms', 'rig p99 latency', 'rig p99 ms', 'lower', kind='rig', unit='ms', fmt='.4g'
    ),
    MetricSpec('rig_drop_rate', 'rig drop rate', 'rig drop rate', 'lower', kind='rig', fmt='.4f'),
)
