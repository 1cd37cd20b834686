"""A run folder read back: run.json (typed) with its frames.csv rows."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

from replaybench.errors import SourceError
from replaybench.results.io import read_run_result
from replaybench.results.records import FrameRecord, read_frames_csv

if TYPE_CHECKING:
    from replaybench.results.model import RunResult

__all__ = ['RunData', 'load_run']


class RunData(NamedTuple):
    """A run folder as read back: run.json (typed), frames.csv rows and the folder."""

    run: RunResult
    frames: list[FrameRecord]
    dir: Path


def load_run(run_dir: str | Path) -> RunData:
    """Read a run folder; SourceError with the reason when it is not a readable run."""
    run_dir = Path(run_dir)
    run_json = run_dir / 'run.json'
    if not run_dir.is_dir():
        msg = f'{run_dir}: not a directory (expected a replaybench run folder)'
        raise SourceError(msg) from None
    if not run_json.exists():
        msg = f'{run_dir}: no run.json (not a replaybench run folder, or the run did not finish)'
        raise SourceError(msg) from None
    run = read_run_result(run_json)
    name = run.outputs.frames_csv if run.outputs is not None else 'frames.csv'
    frames_csv = run_dir / (name or 'frames.csv')
    if not frames_csv.resolve().is_relative_to(run_dir.resolve()):
        msg = f'{run_json}: outputs.frames_csv {name!r} points outside the run folder'
        raise SourceError(msg) from None
    if not frames_csv.is_file():
        msg = f'{run_dir}: {frames_csv.name} is missing'
        raise SourceError(msg) from None
    return RunData(run=run, frames=read_frames_csv(frames_csv), dir=run_dir)
