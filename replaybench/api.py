"""The Python API: ``import replaybench as rb`` (docs/api.md).

``rb.run`` replays bags through backends, ``rb.load_run`` reads a run folder back,
``rb.compare`` compares runs with confidence intervals and a gate, ``rb.peak`` finds a
backend's peak sustainable rate and ``rb.sweep`` runs a grid of runs on Ray. Each takes the
options of the command of the same name, in snake_case, and returns a typed result
(``replaybench.results.model``) whose tables are pandas DataFrames.

Library calls install no signal handler (pass ``stop=``, a ``threading.Event``, to end a run
early), leave ``os.environ``, OpenCV's thread count, ``sys.argv`` and the running threads as
they found them, print nothing (pass ``progress=`` to follow a run) and, without ``out``, write
nothing.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec, TypeVar

from replaybench._environ import kept_environ

if TYPE_CHECKING:
    import os
    import threading
    from collections.abc import Callable, Sequence

    from replaybench.app.sweep import SweepProgress, SweepResult
    from replaybench.replay.peak import Trial
    from replaybench.results.model import Comparison, PeakResult, RunResult

__all__ = ['compare', 'load_run', 'peak', 'run', 'sweep']

_P = ParamSpec('_P')
_R = TypeVar('_R')


def _keeps_environ(call: Callable[_P, _R]) -> Callable[_P, _R]:
    """``call`` leaves ``os.environ`` as it found it (``kept_environ``): what the libraries it
    loads set there is undone when it returns."""

    @functools.wraps(call)
    def kept(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        with kept_environ():
            return call(*args, **kwargs)

    return kept


@_keeps_environ
def run(
    input: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    backends: str | Sequence[str] = ('hsv',),
    out: str | os.PathLike[str] | None = None,
    rate: str | float = 'max',
    topics: str | Sequence[str] | None = None,
    threads: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    stop: threading.Event | None = None,
    **options: Any,
) -> RunResult:
    """Replay ``input`` (a bag, a rosbag2 folder, or several) through ``backends``.

    ``rate``: ``'max'``, ``'recorded'``, ``'2x'``, ``'30hz'`` or a number of Hz. ``out``: the
    run folder to write, exactly the one ``replaybench run --out`` writes; None (default) keeps
    everything in memory and writes nothing. ``options`` are ``replaybench run``'s other
    options in snake_case (``max_frames=``, ``warmup=``, ``ground_truth=``, ``model=``,
    ``force=``, ``report=False`` for ``--no-report``, ``detections_format=`` for
    ``--format``; see ``replaybench.app.run.run_config``). ``progress(done, total)`` is called
    as frames are replayed; setting ``stop`` ends the run at the next frame (status
    ``interrupted``).

    Returns the ``RunResult``: run.json's contents as typed attributes, with ``frames`` and
    ``summary`` as pandas DataFrames (the frames.csv and summary.csv tables). Raises
    ``ReplaybenchError`` subclasses for bad input and options and for a run that measured
    nothing.
    """
    from replaybench.app.run import run_benchmark, run_config

    config = run_config(
        input,
        backends=backends,
        out=out,
        rate=rate,
        topics=topics,
        threads=threads,
        **options,
    )
    # built as the files hold it (JSON values, times rounded as in frames.csv), whether or not
    # they were written: rb.load_run(out) equals it
    return run_benchmark(config, progress=progress, stop=stop).run


@_keeps_environ
def load_run(path: str | os.PathLike[str]) -> RunResult:
    """A run folder read back: run.json as a ``RunResult`` with its frames.csv (``frames``).

    ``rb.load_run(folder)`` equals the ``RunResult`` that ``rb.run(..., out=folder)`` returned,
    DataFrames included. Raises ``SourceError`` when the folder is not a readable run.
    """
    from replaybench.results.folder import load_run as read_folder

    data = read_folder(Path(path))
    return dataclasses.replace(data.run, frame_records=tuple(data.frames))


@_keeps_environ
def compare(
    *runs: RunResult | str | os.PathLike[str],
    fail_if: str | Sequence[str] = (),
    strict: bool = False,
    allow_inconclusive: bool = False,
    baseline: int = 0,
    baseline_backend: str | None = None,
    seed: int = 0,
    out: str | os.PathLike[str] | None = None,
    markdown: str | os.PathLike[str] | None = None,
) -> Comparison:
    """Compare runs (run folders, or ``RunResult``s of ``rb.run``; the first is the baseline),
    as ``replaybench compare`` does.

    ``fail_if``: gate conditions such as ``'p99_ms > +10%'``; ``strict`` judges them on the
    point estimate; ``allow_inconclusive`` makes an undecided gate pass. ``out``: also write
    comparison.csv/.json/.html there. ``markdown``: also write the comparison as
    GitHub-flavoured Markdown to that file (as ``--markdown FILE``). Returns the ``Comparison``
    (comparison.json's contents) with ``table``, the comparison.csv rows as a pandas DataFrame,
    and ``verdict`` (``passed``, ``failed``, ``inconclusive``; None without conditions).
    """
    from replaybench.app.compare import compare_config, run_compare
    from replaybench.comparison.output import CSV_COLUMNS, comparison_json, csv_rows
    from replaybench.errors import UsageError
    from replaybench.results.folder import RunData
    from replaybench.results.io import from_json
    from replaybench.results.model import Comparison, RunResult

    items: list[str | Path | RunData] = []
    for index, item in enumerate(runs):
        if isinstance(item, RunResult):
            if item.frame_records is None:
                msg = f'run {index} carries no frames: make it with rb.run or rb.load_run'
                raise UsageError(msg)
            items.append(RunData(item, list(item.frame_records), Path(f'run{index}')))
        else:
            items.append(Path(item))
    settings = compare_config(
        items,
        fail_if=fail_if,
        strict=strict,
        allow_inconclusive=allow_inconclusive,
        baseline=baseline,
        baseline_backend=baseline_backend,
        seed=seed,
        out=out,
        markdown=markdown,
    )
    outcome = run_compare(settings)
    comparison, gate = outcome.comparison, list(outcome.gate)
    document = comparison_json(
        comparison,
        gate=gate,
        conditions=settings.fail_if,
        strict=strict,
        allow_inconclusive=allow_inconclusive,
    )
    result = from_json(Comparison, document, where='comparison')
    return dataclasses.replace(
        result, table_rows=tuple(csv_rows(comparison, gate)), table_columns=tuple(CSV_COLUMNS)
    )


@_keeps_environ
def peak(
    input: str | os.PathLike[str],
    *,
    backend: str = 'hsv',
    out: str | os.PathLike[str] | None = None,
    max_drop: float = 0.05,
    p99_ms: float | None = None,
    trial_frames: int | None = None,
    min_hz: float = 1.0,
    max_hz: float | None = None,
    refine_steps: int = 4,
    topics: str | Sequence[str] | None = None,
    threads: int | None = None,
    force: bool = False,
    report: bool = True,
    progress: Callable[[Trial], None] | None = None,
    stop: threading.Event | None = None,
    cameras: bool = False,
    max_copies: int = 32,
    **options: Any,
) -> PeakResult:
    """The highest fixed rate at which ``backend`` keeps up with ``input``, as ``replaybench
    peak`` finds it (docs/peak.md).

    ``out``: the peak folder (peak.json, peak.html unless ``report=False``, and the trial
    runs); None keeps every trial in memory and writes nothing. ``options``: the backend
    options of ``replaybench peak`` (``config=``, ``model=``, ``device=``, ...).
    ``progress(trial)`` is called after each trial. Returns the ``PeakResult`` (peak.json's
    contents) with ``peak_hz`` and ``trials``, a pandas DataFrame (``rate_hz``, ``ok``, ...).
    ``cameras``: instead of a rate, the most copies of the bag's camera set sustained at the
    recorded rate, at most ``max_copies`` (``PeakResult.cameras``, docs/rigs.md).
    """
    from replaybench.app.peak import peak_config, run_peak

    settings = peak_config(
        input,
        backend=backend,
        out=out,
        max_drop=max_drop,
        p99_ms=p99_ms,
        trial_frames=trial_frames,
        min_hz=min_hz,
        max_hz=max_hz,
        refine_steps=refine_steps,
        topics=topics,
        threads=threads,
        force=force,
        report=report,
        cameras=cameras,
        max_copies=max_copies,
        **options,
    )
    record = run_peak(settings, progress=progress, stop=stop).record
    assert record is not None  # the search always sets it
    return record


@_keeps_environ
def sweep(
    inputs: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    backends: str | Sequence[str] = ('hsv',),
    out: str | os.PathLike[str],
    progress: Callable[[SweepProgress], None] | None = None,
    stop: threading.Event | None = None,
    **options: Any,
) -> SweepResult:
    """Every input x backend x ``params`` combination as one run on Ray, as ``replaybench
    sweep`` does (docs/sweep.md; needs the ``sweep`` extra). ``out`` is the sweep folder
    (the same ``out`` resumes); ``options`` are the command's other options in snake_case
    (``params=['hsv.min_area=50,100']``, ``address=``, ``pack=``, ``max_frames=``, ...);
    setting ``stop`` ends it as interrupted, the complete cells kept. Returns the
    ``SweepResult``; its ``cells`` is a pandas DataFrame (sweep.csv).
    """
    from replaybench.app.run import input_paths, name_list
    from replaybench.app.sweep import run_sweep, sweep_config

    settings = sweep_config(
        input_paths(inputs), backends=name_list(backends), out=Path(out), **options
    )
    return run_sweep(settings, progress=progress, stop=stop)
