"""One cell where Ray placed it: check the input cheaply, run it, send its files back.

A cell is exactly a ``replaybench run`` of one input through one backend: the ``RunConfig``
the ``run`` command builds from the same ``RunOptions`` (``replaybench.app.run.config_of``),
with the cell's ``--param`` values applied and the input's digest, computed once by the driver,
given to it, so that nothing is hashed on the node while frames are measured. The node checks
the input by its data files' sizes and modification times; only where those differ from the
driver's is the digest computed, before the run.
"""

from __future__ import annotations

import os
import socket
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench import _version
from replaybench.app.sweep.plan import cell_options
from replaybench.errors import SourceError, UsageError

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.app.options import RunOptions
    from replaybench.app.sweep.plan import Cell, InputId
    from replaybench.replay.runner import RunConfig

__all__ = ['Board', 'cell_run_config', 'check_input', 'execute_cell']


def cell_run_config(
    cell: Cell, options: RunOptions, out_dir: Path, command: Sequence[str]
) -> RunConfig:
    """The ``RunConfig`` the ``run`` command builds for this input, backend and options, with
    the cell's ``--param`` values applied and the driver's digest of the input."""
    from replaybench.app.run import config_of

    made = cell_options(options.backend_options(), dict(cell.params))
    known = (cell.input.sha256,) if cell.input.sha256 is not None else None
    # the cell's values as its instance's own parameters: run.json records them
    config = config_of(
        options,
        [cell.input.path],
        backends=[cell.backend_text],
        params=[f'{cell.backend}.{k}={v}' for k, v in cell.params],
        out=out_dir,
        command=command,
        input_sha256=known if options.hash_inputs else None,
    )
    return replace(config, threads=made.threads)


def check_input(inp: InputId, host: str) -> None:
    """SourceError unless the node sees the input the driver hashed (shared storage): the same
    data files with the same sizes, and the same modification times or else the same digest."""
    from replaybench.sources.digest import files_sha256

    stale = False
    for stamp in inp.files:
        try:
            found = stamp.path.stat()
        except OSError as err:
            msg = (
                f'{inp.path} is not readable on node {host} (inputs must be on shared storage): '
                f'{stamp.path}: {err.strerror or err}'
            )
            raise SourceError(msg) from err
        if found.st_size != stamp.size_bytes:
            msg = (
                f"{inp.path} on node {host} differs from the driver's copy ({stamp.path.name}: "
                f'{found.st_size} bytes instead of {stamp.size_bytes})'
            )
            raise SourceError(msg)
        stale = stale or found.st_mtime_ns != stamp.mtime_ns
    if not stale:
        return
    if inp.sha256 is None:
        msg = (
            f"{inp.path} on node {host} has other modification times than the driver's copy "
            'and, with --no-hash, cannot be compared by content'
        )
        raise SourceError(msg)
    try:
        sha = files_sha256([s.path for s in inp.files])
    except OSError as err:
        msg = f'{inp.path} is not readable on node {host}: {err.strerror or err}'
        raise SourceError(msg) from err
    if sha != inp.sha256:
        msg = (
            f"{inp.path} on node {host} differs from the driver's copy "
            f'(sha256 {sha[:12]} instead of {inp.sha256[:12]})'
        )
        raise SourceError(msg)


def execute_cell(
    cell: Cell, options: RunOptions, command: Sequence[str], version: str, board: Any
) -> dict[str, Any]:
    """Run one cell where Ray placed it; the run folder's files come back as bytes, with the
    cell's metrics computed here from the records in memory (after the run has ended)."""
    import ray

    from replaybench.app.sweep.engine import error_line
    from replaybench.app.sweep.record import cell_metrics

    started = time.time()
    context = ray.get_runtime_context()
    where = {
        'node_id': context.get_node_id(),
        'node_ip': ray.util.get_node_ip_address(),
        'hostname': socket.gethostname(),
        'gpu_ids': [str(g) for g in ray.get_gpu_ids()],
        'pid': os.getpid(),
    }
    if board is not None:
        board.start.remote(cell.index, where['node_id'])
    report: dict[str, Any] = {'index': cell.index, 'where': where, 'started_at': started}
    try:
        if version != _version.__version__:
            msg = (
                f'node {where["hostname"]} has replaybench {_version.__version__}, '
                f'the driver {version}'
            )
            raise UsageError(msg)
        check_input(cell.input, str(where['hostname']))
        with tempfile.TemporaryDirectory(prefix='replaybench-cell-') as tmp:
            out = Path(tmp) / 'run'
            from replaybench.app.run import run_benchmark

            outcome = run_benchmark(cell_run_config(cell, options, out, command))
            finished = time.time()
            files = {
                p.relative_to(out).as_posix(): p.read_bytes()
                for p in sorted(out.rglob('*'))
                if p.is_file()
            }
        if outcome.status in ('complete', 'interrupted'):
            report['status'] = outcome.status
            report['files'] = files
            if outcome.status == 'complete':
                # frames.csv's rows as the file holds them (times rounded as written)
                records = list(outcome.run.frame_records or ())
                report['metrics'] = cell_metrics(outcome.run, records, cell.key)
        else:  # one backend per cell: no other status is expected
            report['status'] = 'failed'
            report['error'] = f'the run ended with status {outcome.status}'
        report['finished_at'] = finished
    except Exception as err:  # noqa: BLE001  one line per failed cell; the other cells go on
        report['status'] = 'failed'
        report['error'] = error_line(err)
        report['finished_at'] = time.time()
    return report


class Board:
    """A Ray actor the cells tell when they start, for the progress line."""

    def __init__(self) -> None:
        self.started: dict[int, str] = {}

    def start(self, index: int, node_id: str) -> None:
        self.started[index] = node_id

    def snapshot(self) -> dict[int, str]:
        return dict(self.started)
