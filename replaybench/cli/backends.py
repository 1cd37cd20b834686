"""``replaybench backends`` and ``replaybench doctor``: what can run on this machine."""

from __future__ import annotations

import typer

from replaybench.cli._common import app, echo

__all__: list[str] = []


@app.command()
def backends() -> None:
    """List the backends, whether each is available on this machine, and why not.

    Example: replaybench backends
    """
    from replaybench.backends import backend_table

    rows = backend_table()
    width = max((len(r.name) for r in rows), default=4)
    for r in rows:
        state = 'available' if r.availability.ok else f'unavailable: {r.availability.reason}'
        typer.echo(f'{r.name.ljust(width)}  {state}  - {r.description} [{r.origin}]')


@app.command()
def doctor() -> None:
    """Check this machine for the GPU backends: NVIDIA driver, the CUDA, cuDNN and TensorRT
    libraries, onnxruntime / torch / CuPy builds, and what each GPU backend needs.

    Exit status 0 when every GPU backend can run here, 1 when one cannot.

    Example: replaybench doctor
    """
    from replaybench.backends.gpu.doctor import gpu_report

    found = gpu_report()
    for line in found.lines():
        echo(line)
    if not found.ok:
        raise typer.Exit(1)
