"""``replaybench peak``: the highest rate a backend sustains."""

from __future__ import annotations

import sys
import threading
from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated, Any

import typer

from replaybench.cli._common import (
    EXIT_INTERRUPTED,
    app,
    echo,
    fail,
    fmt,
    with_instance_options,
    with_run_options,
)
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
@with_run_options('peak')
@with_instance_options('peak')
def peak(
    bag: Annotated[Path, typer.Argument(help='Bag file or rosbag2 folder.', show_default=False)],
    out: Annotated[
        Path | None,
        typer.Option('--out', '-o', help='Folder for peak.json, peak.html and the trial runs.'),
    ] = None,
    force: Annotated[
        bool, typer.Option('--force', help='Replace the peak folder --out, once the sweep ends.')
    ] = False,
    max_drop: Annotated[
        float,
        typer.Option('--max-drop', min=0.0, max=1.0, help='Largest dropped fraction allowed.'),
    ] = 0.05,
    p99_ms: Annotated[
        float | None, typer.Option('--p99-ms', min=0.0, help='Latency p99 bound in ms.')
    ] = None,
    trial_frames: Annotated[
        int | None,
        typer.Option('--trial-frames', min=2, help='Frames per trial (default: up to 300).'),
    ] = None,
    min_hz: Annotated[float, typer.Option('--min-hz', min=0.001, help='Lowest rate tried.')] = 1.0,
    max_hz: Annotated[
        float | None, typer.Option('--max-hz', min=0.001, help='Highest rate tried.')
    ] = None,
    refine_steps: Annotated[
        int, typer.Option('--refine-steps', min=0, help='Bisection steps after the coarse search.')
    ] = 4,
    cameras: Annotated[
        bool,
        typer.Option(
            '--cameras',
            help='Find how many copies of the camera set the backend sustains at the recorded '
            'rate (docs/rigs.md).',
        ),
    ] = False,
    max_copies: Annotated[
        int, typer.Option('--max-copies', min=1, help='With --cameras: the most copies tried.')
    ] = 32,
    *,
    backend: str,
    param: list[str],
    options: dict[str, Any],
) -> None:
    """Find the highest replay rate a backend sustains without dropping frames.

    Example: replaybench peak fixtures/bags/jpeg.mcap --backend hsv --max-drop 0.05 --out runs/peak

    With --cameras: replaybench peak rig/rig.mcap --backend hsv --cameras --out runs/peak-rig
    """
    from replaybench.app.peak import peak_config, run_peak
    from replaybench.app.signals import stop_on_signals
    from replaybench.replay.runner import new_run_dir

    def show(trial: Any) -> None:
        verdict = 'pass' if trial.ok else 'fail'
        what = f'{trial.rate_hz:g} Hz' if trial.copies is None else f'{trial.copies} x rig'
        typer.echo(
            f'{what}: dropped {trial.dropped}/{trial.frames}, '
            f'p99 {fmt(trial.p99_ms)} ms, {verdict}',
            err=True,
        )

    token = threading.Event()
    try:
        settings = peak_config(
            bag,
            backend=backend,
            params=param,
            out=out if out is not None else new_run_dir(),
            max_drop=max_drop,
            p99_ms=p99_ms,
            trial_frames=trial_frames,
            min_hz=min_hz,
            max_hz=max_hz,
            refine_steps=refine_steps,
            force=force,
            command=['replaybench', *sys.argv[1:]],
            cameras=cameras,
            max_copies=max_copies,
            **options,
        )
        with stop_on_signals(token):
            result = run_peak(settings, progress=show, stop=token)
    except ReplaybenchError as err:
        raise fail(err) from None
    folder = settings.out
    assert folder is not None  # the command line always writes a folder
    if settings.cameras:
        _show_cameras(settings.backend, result)
    else:
        _show_rates(settings.backend, result)
    for warning in result.warnings:
        echo(f'replaybench: warning: {warning}', err=True)
    echo(f'Peak folder: {folder}')
    if (folder / 'peak.html').exists():
        echo(f'Report: {folder / "peak.html"}')
    if result.status == 'interrupted':
        raise typer.Exit(EXIT_INTERRUPTED)


def _show_rates(backend: str, result: Any) -> None:
    typer.echo(f'{"rate Hz":>10}  {"frames":>6}  {"dropped":>7}  {"p99 ms":>8}  verdict')
    for t in result.trials:
        verdict = 'pass' if t.ok else 'fail'
        typer.echo(
            f'{t.rate_hz:>10.3f}  {t.frames:>6}  {t.dropped:>7}  {fmt(t.p99_ms):>8}  {verdict}'
        )
    if result.peak_hz is None:
        typer.echo(f'{backend}: no rate tried met the limits')
    else:
        typer.echo(f'{backend}: peak sustainable rate {result.peak_hz:.3f} Hz')


def _show_cameras(backend: str, result: Any) -> None:
    rig = result.record.cameras
    typer.echo(
        f'{"copies":>6}  {"cameras":>7}  {"frames":>6}  {"dropped":>7}  {"p99 ms":>8}  verdict'
    )
    for t in result.trials:
        verdict = 'pass' if t.ok else 'fail'
        typer.echo(
            f'{t.copies:>6}  {t.copies * len(rig.cameras):>7}  {t.frames:>6}  {t.dropped:>7}  '
            f'{fmt(t.p99_ms):>8}  {verdict}'
        )
    what = (
        f'{len(rig.cameras)} camera{"s" if len(rig.cameras) != 1 else ""} at {rig.recorded_hz:g} Hz'
    )
    typer.echo(f'{backend}: sustains {rig.copies or 0} x this rig ({what})')
    if result.record.limit_reached:
        typer.echo(f'{backend}: every count up to --max-copies passed: it may sustain more')
    if rig.predicted_copies is not None:
        typer.echo(
            f"{backend}: predicted at most {rig.predicted_copies} x from one camera's service "
            f'time {rig.service_ms:.2f} ms on {rig.cores} core{"s" if rig.cores != 1 else ""}: '
            f'floor({rig.cores} / ({len(rig.cameras)} x {rig.recorded_hz:g} Hz x '
            f'{rig.service_ms:.2f} ms))'
        )
