"""What a task type is to the rest of replaybench: its name, the metrics it is judged on, the
recorded outputs of it that the ``recorded`` backend reads and, for a task scored against ground
truth, how its truth is found and read (``TaskTruth``).

A metric's name, labels, unit, number format, better direction and the tables that show it
live in one ``MetricSpec``; compare, its gate, comparison.html/.csv/.json, the sweep and the
terminal tables read them from the registered tasks (``replaybench.tasks.all_metrics``) and
from ``COMMON_METRICS`` (``replaybench.tasks.common``) instead of keeping lists of their own.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, NamedTuple, Protocol, TypeVar, runtime_checkable

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.decode.recorded import OutputReader
    from replaybench.sinks.writer import OutputWriter
    from replaybench.sources import Source
    from replaybench.types import BackendResult

__all__ = [
    'Better',
    'LazyMapping',
    'MetricKind',
    'MetricSpec',
    'Task',
    'TaskRecording',
    'TaskRecordingBase',
    'TaskTruth',
    'TaskViews',
    'TerminalColumns',
    'TruthInput',
]

_V = TypeVar('_V')

#: ``timing``: a latency or a rate of the replay, compared as a ratio with an interval;
#: ``recorded``: the latency a recording's outputs had on the robot, compared as timings are;
#: ``accuracy``: a figure against ground truth, compared as a difference of point estimates;
#: ``rig``: a figure of a rig row (all of a backend's cameras, ``replaybench.results.rig``),
#: compared and gated on rig rows only.
MetricKind = Literal['timing', 'recorded', 'accuracy', 'rig']
#: Which way the metric improves.
Better = Literal['higher', 'lower']
#: Where ``replaybench run``'s table shows a task's metrics (those with a ``terminal_label``):
#: ``always``: for every row, before the memory column (every backend has boxes);
#: ``scored``: after the memory column, and only where a row has the task's summary.
TerminalColumns = Literal['always', 'scored']


@dataclass(frozen=True, slots=True)
class MetricSpec:
    """One metric: how it is named, written and where it is shown."""

    #: its name in summary.csv, run.json, comparison.csv and ``--fail-if`` (``map50``)
    name: str
    #: its name in sentences: the gate's lines (``mAP@0.5``, ``p99 latency``)
    label: str
    #: its table heading: comparison.html (``R@0.5``, ``p99 ms``)
    short_label: str
    better: Better
    kind: MetricKind = 'accuracy'
    #: the unit written after a value or a change in the gate's lines (``ms``; '' for none:
    #: an accuracy metric's label names its unit)
    unit: str = ''
    #: the format of a value in the gate's lines (the unit follows it)
    fmt: str = '.4f'
    #: ``compare`` compares it and ``--fail-if`` may gate on it
    gate: bool = True
    #: a sweep shows it: a column of sweep.csv, the mean over a cell's topics
    sweep: bool = False
    #: the task's main figure, shown first in comparison.html's summary
    main: bool = False
    #: its columns follow those of the metrics that are not appended (comparison.csv: after
    #: ``flags``; compare's tables and sweep.csv: after the other accuracy metrics), so that
    #: readers of the earlier columns keep them; a new task's metrics are appended
    appended: bool = True
    #: other names ``--fail-if`` accepts for it (``p50_ms``)
    aliases: tuple[str, ...] = ()
    #: its heading in the terminal's tables (``replaybench run``, ``replaybench sweep``);
    #: None where it is not shown there
    terminal_label: str | None = None
    #: digits after the point in the terminal's tables
    terminal_digits: int = 3
    #: ``report --github-benchmark`` tracks it (bigger_is_better.json, unit ``fraction``)
    tracked: bool = False

    @property
    def accuracy(self) -> bool:
        """An accuracy metric: compared as a difference of point estimates, without interval."""
        return self.kind == 'accuracy'

    def value_text(self, value: float) -> str:
        """``value`` as the gate's lines write it: ``0.9120``, ``12.5 ms``."""
        unit = f' {self.unit}' if self.unit else ''
        return f'{value:{self.fmt}}{unit}'


@dataclass(frozen=True, slots=True)
class TaskViews:
    """How a task shows on report.html and the terminal, beside its metrics' specs.

    Each view is a ``'module:attr'`` string, imported when it is shown (the report, the end of a
    run), never with the task; None where the task has no such view. A task without a
    ``views`` attribute has none (``replaybench.tasks.task_views``).
    """

    #: the ``SummaryRow`` field holding a row's full summary of the task (``accuracy``,
    #: ``tag_accuracy``, ``segmentation``): a row is the task's where it is not None
    summary_field: str | None = None
    #: ``(rows) -> str``: HTML right under report.html's Summary table ('' for none)
    summary_panel: str | None = None
    #: ``(rows) -> (headings, cells)``: the task's columns of the Summary's "More figures"
    #: table, one tuple of texts per row (no headings: none shown)
    more_columns: str | None = None
    #: ``(rows) -> str``: the task's section of report.html, after the recorded latency
    section_panel: str | None = None
    #: ``(run) -> list[str]``: lines ``replaybench run`` prints after its table
    terminal_lines: str | None = None
    #: ``(out, sample, backend, drawn) -> str``: the picture of what a backend of the task drew
    #: of a topic's sample frame (``TaskRecording.sample``), written into the run folder
    #: ``out`` beside the frame's sample; returns its relative path (``sample``: a
    #: ``replaybench.replay.output.SampleImage``)
    sample_picture: str | None = None
    #: ``(relative path) -> (the frame's sample path, caption) | None``: how report.html's
    #: Samples name a picture of ``sample_picture`` (None: not one of the task's)
    sample_caption: str | None = None
    #: the task's metrics in ``replaybench run``'s table, in its order (each has a
    #: ``terminal_label``), and where they go
    terminal_metrics: tuple[str, ...] = ()
    terminal: TerminalColumns = 'scored'


class LazyMapping(Mapping[str, _V]):
    """A mapping held in another module (``'module:attr'``), imported when first read: a task
    declares its recorded readers so, and nothing of them is imported before they are used."""

    __slots__ = ('_table', 'target')

    def __init__(self, target: str) -> None:
        self.target = target
        self._table: Mapping[str, _V] | None = None

    def _load(self) -> Mapping[str, _V]:
        if self._table is None:
            module_name, _, attr = self.target.partition(':')
            table: Mapping[str, _V] = getattr(importlib.import_module(module_name), attr)
            self._table = table
        return self._table

    def __getitem__(self, key: str) -> _V:
        return self._load()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __len__(self) -> int:
        return len(self._load())

    def __repr__(self) -> str:
        return f'LazyMapping({self.target!r})'


@runtime_checkable
class Task(Protocol):
    """A task type (boxes, AprilTags, segmentation masks): registered in ``replaybench.tasks``."""

    @property
    def name(self) -> str:
        """The registry name (``tags``)."""
        ...

    @property
    def metrics(self) -> tuple[MetricSpec, ...]:
        """The task's metrics, in table order."""
        ...

    @property
    def recorded_readers(self) -> Mapping[str, OutputReader]:
        """What the ``recorded`` backend reads of this task: a message type (ROS 2 spelling)
        -> its reader (``replaybench.decode.recorded.OutputReader``); empty for none."""
        ...


class TruthInput(NamedTuple):
    """One input as a task's ``open_truth`` sees it: opened, its camera topics chosen."""

    #: its index among the run's inputs
    number: int
    path: Path
    source: Source
    #: every readable image topic the input holds, truth topics among them
    images: tuple[str, ...]
    #: the image topics the run replays of it
    replayed: tuple[str, ...]


@runtime_checkable
class TaskTruth(Protocol):
    """How a task finds and reads its ground truth (a task without truth has none of these).

    The engine calls them for every registered task, in the registry's order, and never names
    one: ``load_truth`` once per run before any input opens, ``truth_topics`` and then
    ``open_truth`` as each input opens (before the first frame: a reader reads there only what
    must be read before it; what it can read later it reads on first use). ``options`` is the
    run's ``replaybench.replay.config.InputOptions`` and ``config`` its ``RunConfig`` (typed
    loosely: tasks/ sits below replay/). A bad truth (a topic asked for that is not there, a file
    that does not parse) is a ``UsageError`` or ``SourceError`` with one line; a truth message
    that cannot be read is left out with a line in ``notes``, which become the input's warnings.
    """

    def truth_topics(self, options: Any) -> frozenset[str]:
        """The topics holding the task's truth: never replayed as a camera, never picked as
        the recorded topic."""
        ...

    def load_truth(self, config: Any) -> object | None:
        """What the run reads of the task's truth once, for every input (a ground-truth file,
        a folder of masks); None for nothing. Given back to ``open_truth`` as ``loaded``."""
        ...

    def open_truth(
        self, inp: TruthInput, options: Any, loaded: object | None, notes: list[str]
    ) -> object | None:
        """The input's truth of the task, as the task's scoring reads it; None where the input
        has none."""
        ...


#: a processed frame as a task's recording sees it: (topic, seq, log_time_ns, stamp_ns, frame_id)
FrameKey = tuple[str, int, int, int, str]


@runtime_checkable
class TaskRecording(Protocol):
    """A task's part of recording the processed frames of its backends: the lifecycle the
    engine (``replaybench.replay.recording.Recorder``, ``replaybench.replay.record``) drives
    without knowing the task.

    Made once per run by the task's ``recording`` (``'module:attr'`` of a callable ``(recorder)
    -> TaskRecording``) when the frames of a backend that declares the task are first recorded;
    ``frame`` is called per processed frame of the first pass, after the pass, outside any timed
    region; the rest once, after the passes: ``finish`` before outputs.mcap closes,
    ``warnings`` into run.json's warnings, ``summary`` for each (backend, topic) row,
    ``run_fields`` for run.json. ``TaskRecordingBase`` gives every method but ``frame`` a
    default that adds nothing.
    """

    @property
    def scores_boxes(self) -> bool:
        """Whether the frame's boxes are scored against box ground truth (not a mask's)."""
        ...

    @property
    def writes_first(self) -> bool:
        """Whether its messages go before the frame's detections message (their channels
        come first in outputs.mcap), else after it."""
        ...

    def frame(
        self,
        writer: OutputWriter,
        label: str,
        inp: Any,
        key: FrameKey,
        result: BackendResult,
    ) -> Mapping[str, Any]:
        """The frame's outputs written into ``writer`` and scored (``inp``: the
        ``replaybench.replay.inputs.OpenedInput``, its task truth in ``inp.truth[name]``); the
        task's own ``FrameRecord`` fields of it (none: an empty mapping)."""
        ...

    def sample(self, result: BackendResult) -> Any:
        """What the sample picture draws of the frame beside its boxes (a mask's labels), or
        None."""
        ...

    def finish(self, writer: OutputWriter) -> None:
        """After the passes, before outputs.mcap closes: what the task writes once (metadata)."""
        ...

    def warnings(self) -> list[str]:
        """Lines for run.json's warnings and the terminal."""
        ...

    def summary(self, backend: str, topic: str) -> Mapping[str, Any] | None:
        """The task's part of the (backend label, topic) row: ``SummaryRow`` fields by name
        (a built-in task's metrics and full summary), and for a task without fields of its own
        its metrics by ``MetricSpec.name`` (numbers or None, into ``SummaryRow.task_metrics``);
        None where the row is not the task's."""
        ...

    def run_fields(self) -> Mapping[str, Any]:
        """``RunResult`` fields the task fills (the agreement of its backends); empty for
        none."""
        ...


class TaskRecordingBase:
    """Defaults of a ``TaskRecording``: boxes scored, messages after the detections, nothing
    drawn, written, warned, summarised or added to run.json. A task's recording subclasses it
    and defines ``frame`` and what it adds."""

    scores_boxes: bool = True
    writes_first: bool = False

    def sample(self, result: BackendResult) -> Any:
        """Nothing beside the boxes."""
        del result

    def finish(self, writer: OutputWriter) -> None:
        """Nothing written once."""
        del writer

    def warnings(self) -> list[str]:
        """No lines."""
        return []

    def summary(self, backend: str, topic: str) -> Mapping[str, Any] | None:
        """No row is the task's."""
        del backend, topic
        return None

    def run_fields(self) -> Mapping[str, Any]:
        """Nothing for run.json."""
        return {}
