"""``replaybench sweep``'s options as one config (``sweep_config``) and the sweep itself
(``run_sweep``): plan, resume, run on Ray, write the folder."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.app.options import run_options
from replaybench.app.sweep.driver import Driver
from replaybench.app.sweep.plan import (
    DEFAULT_MAX_RETRIES,
    InputId,
    SweepConfig,
    check_backend_options,
    input_identity,
    parse_params,
    plan_cells,
)
from replaybench.errors import UsageError

if TYPE_CHECKING:
    import threading
    from collections.abc import Callable, Sequence

    from replaybench.app.sweep.record import SweepProgress, SweepResult

__all__ = ['DEFAULT_MAX_RETRIES', 'SweepConfig', 'run_sweep', 'sweep', 'sweep_config']


def sweep_config(
    inputs: Sequence[str | Path],
    *,
    backends: Sequence[str],
    out: str | Path,
    params: Sequence[str] = (),
    address: str | None = None,
    pack: bool = False,
    max_retries: int = DEFAULT_MAX_RETRIES,
    command: Sequence[str] | None = None,
    **options: Any,
) -> SweepConfig:
    """The ``SweepConfig`` of ``replaybench sweep``'s options: ``params`` (``--param``),
    ``address``, ``pack``, ``max_retries`` and, in ``options``, every run option of
    ``replaybench run`` (``RunOptions``: ``max_frames=``, ``device=``, ``detections_format=``,
    ``hash_inputs=False``, ``ground_truth_file=``, ...). Raises ``UsageError`` naming the option
    for a bad value, before anything is read or run; ``TypeError`` for an unknown keyword."""
    from replaybench.replay.rate import parse_rate

    if not inputs:
        msg = 'no input given: name one or more bags'
        raise UsageError(msg)
    if not backends:
        msg = 'no backend given: add --backend NAME (see `replaybench backends`)'
        raise UsageError(msg)
    from replaybench.replay.instances import parse_backend, parse_instances

    if len(set(backends)) != len(backends):
        msg = 'each --backend may be given once'
        raise UsageError(msg)
    # labels checked as a run checks them (one label each, no '+', '=' or '.')
    parse_instances(backends)
    instances = [parse_backend(text) for text in backends]
    labels = tuple(label for label, _ in instances)
    if max_retries < 0:
        msg = f'--max-retries must be >= 0, not {max_retries}'
        raise UsageError(msg)
    checked = run_options(**options)
    if isinstance(checked.rate, str):
        parse_rate(checked.rate)
    # every node reads the files the cells name at the same path
    absolute = {
        name: Path(value).resolve()
        for name in ('config', 'model', 'ground_truth_file')
        if (value := getattr(checked, name)) is not None
    }
    return SweepConfig(
        inputs=tuple(Path(i) for i in inputs),
        backends=labels,
        kinds={label: name for label, name in instances if label != name},
        out=Path(out),
        axes=parse_params(params, labels),
        address=address,
        pack=pack,
        max_retries=max_retries,
        options=run_options(checked.as_dict(), **absolute),
        command=tuple(command or ()),
    )


def sweep(
    inputs: Sequence[str | Path],
    *,
    backends: Sequence[str],
    out: str | Path,
    progress: Callable[[SweepProgress], None] | None = None,
    stop: threading.Event | None = None,
    **options: Any,
) -> SweepResult:
    """``run_sweep(sweep_config(inputs, backends=..., out=..., **options))``: the keyword
    arguments are ``sweep_config``'s, the ``replaybench sweep`` options."""
    config = sweep_config(inputs, backends=backends, out=out, **options)
    return run_sweep(config, progress=progress, stop=stop)


def run_sweep(
    config: SweepConfig,
    *,
    progress: Callable[[SweepProgress], None] | None = None,
    stop: threading.Event | None = None,
) -> SweepResult:
    """Run every (input, backend, ``--param`` combination) of ``config`` as one run on Ray;
    write ``config.out``.

    Without ``config.address`` a local Ray instance is started and shut down at the end (an
    already initialised Ray connection is used as it is); with it, that cluster is joined as
    it is (``replaybench.app.sweep.engine``). Re-running with the same ``out`` resumes. Raises
    ``ReplaybenchError`` subclasses for an input that cannot be read (nothing run); a failing
    cell is recorded and the others go on (``status`` 'failed'); setting ``stop`` (the command
    line does on Ctrl-C and SIGTERM, ``replaybench.app.signals``), or a ``KeyboardInterrupt``,
    gives ``status`` 'interrupted' with the complete cells kept. No signal handler is installed.
    """
    ids: list[InputId] = []
    for given in config.inputs:
        identity = input_identity(given, str(given), digest=config.options.hash_inputs)
        if any(i.path == identity.path for i in ids):
            msg = f'{given} is given twice'
            raise UsageError(msg)
        ids.append(identity)
    cells = plan_cells(ids, config.backends, config.axes, config.options, config.kinds)
    check_backend_options(cells, config.options)
    driver = Driver(config, cells, ids, progress, stop)
    todo = driver.prepare()
    finished = True
    if todo:
        try:
            finished = driver.run(todo)
        finally:
            driver.finish_concurrency()
    statuses = {e.status for e in driver.entries.values()}
    if not finished:
        status = 'interrupted'
    elif statuses - {'complete'}:
        status = 'failed'
    else:
        status = 'complete'
    return driver.result(status)
