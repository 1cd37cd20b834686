"""``replaybench sweep``: one ordinary run per (input, backend, parameter combination), on Ray.

Each cell is exactly a ``replaybench run`` of one input through one backend (the ``RunConfig``
the ``run`` command builds from the same ``RunOptions``), executed as a Ray task in a fresh
worker process on some node of a Ray cluster: a local one started for the sweep, or any
existing one joined with ``address`` as it is. The task returns the run folder's files to the
driver, which writes them under ``OUT/cells/<name>/`` (the nodes need no shared output folder,
only the inputs at the same path: each cell checks its input's data files first).

The package follows the sweep's flow:

* ``plan``: the ``--param`` axes, the inputs' identities (hashed once, on the driver) and the
  cells with their keys;
* ``engine``: Ray started or joined, and where cells may run (``Placement``);
* ``cell``: one cell on its node;
* ``driver``: resume, submission, collection and the folder's files;
* ``record``: each cell's figures, flags, sweep.csv's rows and the ``SweepResult``;
* ``config``: ``SweepConfig``, ``sweep_config``, ``run_sweep`` and ``sweep``;
* ``terminal``: what the command prints.

Resume: a cell is identified by its key, the hash of the input's size and sha256, the backend,
its parameters, every run option and the replaybench version. A cell folder whose run.json is
complete and carries the same key is kept untouched; only missing, failed or interrupted cells
run again. Outputs: ``sweep.json`` (``replaybench.results.sweepfile.SweepRecord``, schema
``replaybench/schemas/sweep.schema.json``), ``sweep.csv`` (one row per cell) and ``sweep.html``
(inputs x backends). See docs/sweep.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from replaybench.app.options import RunOptions
from replaybench.app.sweep.cell import cell_run_config, execute_cell
from replaybench.app.sweep.config import (
    DEFAULT_MAX_RETRIES,
    SweepConfig,
    run_sweep,
    sweep,
    sweep_config,
)
from replaybench.app.sweep.engine import LOCAL_NODE_IP, NODE_SLOT, join_auth_env, local_ray
from replaybench.app.sweep.plan import (
    Cell,
    InputId,
    ParamAxis,
    cell_options,
    input_identity,
    parse_params,
    plan_cells,
)
from replaybench.app.sweep.record import (
    SweepProgress,
    SweepResult,
    cell_metrics,
    csv_columns,
    csv_rows,
)
from replaybench.app.sweep.terminal import ProgressBar, progress_bar, result_lines
from replaybench.results.sweepfile import SWEEP_SCHEMA_VERSION

if TYPE_CHECKING:
    #: sweep.csv's columns (``csv_columns()``), read from the registered tasks when asked for
    CSV_COLUMNS: tuple[str, ...]
else:

    def __getattr__(name: str) -> tuple[str, ...]:
        if name == 'CSV_COLUMNS':
            return csv_columns()
        msg = f'module {__name__!r} has no attribute {name!r}'
        raise AttributeError(msg)


__all__ = [
    'CSV_COLUMNS',
    'DEFAULT_MAX_RETRIES',
    'LOCAL_NODE_IP',
    'NODE_SLOT',
    'SWEEP_SCHEMA_VERSION',
    'Cell',
    'InputId',
    'ParamAxis',
    'ProgressBar',
    'RunOptions',
    'SweepConfig',
    'SweepProgress',
    'SweepResult',
    'cell_metrics',
    'cell_options',
    'cell_run_config',
    'csv_columns',
    'csv_rows',
    'execute_cell',
    'input_identity',
    'join_auth_env',
    'local_ray',
    'parse_params',
    'plan_cells',
    'progress_bar',
    'result_lines',
    'run_sweep',
    'sweep',
    'sweep_config',
]
