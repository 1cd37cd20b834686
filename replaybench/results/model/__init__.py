"""The typed results: what run.json, peak.json and comparison.json hold, as frozen dataclasses.

``RunResult`` is one run folder's run.json, ``PeakResult`` a ``replaybench peak`` folder's
peak.json and ``Comparison`` the comparison.json of ``replaybench compare``. Nested objects are
typed attributes (``res.settings.rate``, ``res.inputs[0].sha256``, ``res.backends[0].name``);
lists are tuples; objects whose keys are data (``skipped`` reasons, ``warmup_per_topic``) are
mappings, and so are the free-form ones a backend or a sweep fills (``BackendRun.info``,
``RunResult.sweep``).

The classes hold values only: ``replaybench.results.io`` writes them as JSON and reads them
back (``read_run(path) == result`` for a result written with ``write_run``), and the JSON
Schemas in ``replaybench/schemas/`` describe the files. Every field has a default, so a file
written by an older replaybench, which lacks a key, still reads; the schema says which keys a
file written now always has.

A field's JSON key is its name, except where ``metadata['json']`` says otherwise (the
``summary`` rows of run.json are ``RunResult.summary_rows`` and peak.json's ``trials`` are
``PeakResult.trial_rows``: ``summary`` and ``trials`` are kept for tables). A field with
``metadata['omit_none']`` is left out of the file when it is None.

The types live in one module per kind, and are imported from here: ``common`` (the program,
the inputs, the machine), ``run`` (run.json), ``summary`` (a summary row and a repeat's
statistics), the tasks' accuracy types ``detections``, ``tags`` and ``segmentation``, the
tracks task's id-switch timeline ``tracks``,
``sync`` (run.json's ``--sync`` section), ``peak`` (peak.json) and ``comparison``
(comparison.json). Each type's ``__module__`` is this
package, the one place that names it for the API, so that a pickle names
``replaybench.results.model`` whichever module defines the type.
"""

from replaybench.results.model.common import (
    CpuInfo,
    Environment,
    GpuInfo,
    InputInfo,
    OpenCvInfo,
    OsInfo,
    Packages,
    PythonInfo,
    Tool,
    TopicMeta,
)
from replaybench.results.model.comparison import (
    COMPARISON_SCHEMA_VERSION,
    ComparedInput,
    ComparedSettings,
    Comparison,
    ComparisonBaseline,
    ComparisonGate,
    ComparisonRow,
    ComparisonRun,
    ComparisonStatistics,
    GateCheck,
    MetricResult,
)
from replaybench.results.model.detections import Accuracy, AgreementRow
from replaybench.results.model.peak import (
    PEAK_SCHEMA_VERSION,
    PeakCameras,
    PeakResult,
    PeakSettings,
    PeakStart,
    PeakTrial,
)
from replaybench.results.model.rig import RigBackend, RigCamera, RigReport, WorstCamera
from replaybench.results.model.run import (
    RUN_SCHEMA_VERSION,
    BackendFailure,
    BackendRun,
    ReadAhead,
    ResourcePoint,
    Resources,
    ResourceSummary,
    RunCounts,
    RunOutputs,
    RunResult,
    RunSettings,
)
from replaybench.results.model.segmentation import SegmentationAgreementRow, SegmentationSummary
from replaybench.results.model.stereo import StereoAgreementRow
from replaybench.results.model.summary import RepeatStats, SummaryRow
from replaybench.results.model.sync import SyncInput, SyncReport, SyncTopic

# importable from here (the tags' as before), though not in __all__
from replaybench.results.model.tags import TagAccuracy as TagAccuracy
from replaybench.results.model.tags import TagSizeHint as TagSizeHint
from replaybench.results.model.tracks import IdSwitchEvent as IdSwitchEvent
from replaybench.results.model.tracks import TrackLane as TrackLane
from replaybench.results.model.tracks import TrackSpan as TrackSpan
from replaybench.results.model.tracks import TrackTimeline as TrackTimeline

__all__ = [
    'COMPARISON_SCHEMA_VERSION',
    'PEAK_SCHEMA_VERSION',
    'RUN_SCHEMA_VERSION',
    'Accuracy',
    'AgreementRow',
    'BackendFailure',
    'BackendRun',
    'ComparedInput',
    'ComparedSettings',
    'Comparison',
    'ComparisonBaseline',
    'ComparisonGate',
    'ComparisonRow',
    'ComparisonRun',
    'ComparisonStatistics',
    'CpuInfo',
    'Environment',
    'GateCheck',
    'GpuInfo',
    'InputInfo',
    'MetricResult',
    'OpenCvInfo',
    'OsInfo',
    'Packages',
    'PeakCameras',
    'PeakResult',
    'PeakSettings',
    'PeakStart',
    'PeakTrial',
    'PythonInfo',
    'ReadAhead',
    'RepeatStats',
    'ResourcePoint',
    'ResourceSummary',
    'Resources',
    'RigBackend',
    'RigCamera',
    'RigReport',
    'RunCounts',
    'RunOutputs',
    'RunResult',
    'RunSettings',
    'SegmentationAgreementRow',
    'SegmentationSummary',
    'StereoAgreementRow',
    'SummaryRow',
    'SyncInput',
    'SyncReport',
    'SyncTopic',
    'Tool',
    'TopicMeta',
    'WorstCamera',
]


def _name_here(namespace: dict[str, object]) -> None:
    """Give the types that this package's modules define this package as their module, the
    name pickles and reprs give them."""
    for value in namespace.values():
        if isinstance(value, type) and value.__module__.startswith(f'{__name__}.'):
            value.__module__ = __name__


_name_here(globals())
