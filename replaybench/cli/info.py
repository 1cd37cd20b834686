"""``replaybench info``: the topics of a bag."""

from __future__ import annotations

from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated

import typer

from replaybench.cli._common import app, echo, fail, fmt
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
def info(
    bag: Annotated[Path, typer.Argument(help='Bag file or rosbag2 folder.', show_default=False)],
) -> None:
    """Show the camera topics of a bag: types, counts, rates, sizes, encodings and duration.

    Example: replaybench info fixtures/bags/two_camera.mcap
    """
    from replaybench.decode.probe import probe_topics, unreadable_image_topics
    from replaybench.sources import open_source

    try:
        with open_source(bag) as source:
            topics = source.topics()
            cameras = {c.name: c for c in probe_topics(source)}
            skipped = source.skipped_topics()
            unreadable = {t.name for t in unreadable_image_topics(source)}
            truncated = source.truncated
            warnings = list(source.warnings)
    except ReplaybenchError as err:
        raise fail(err) from None
    first = min((t.first_ns for t in topics), default=0)
    last = max((t.last_ns for t in topics), default=0)
    total = sum(t.count for t in topics) + sum(t.count for t in skipped)
    echo(f'path:       {bag}')
    typer.echo(f'format:     {source.format}{" (truncated)" if truncated else ""}')
    typer.echo(f'duration:   {(last - first) / 1e9:.3f} s')
    typer.echo(f'messages:   {total}')
    typer.echo('camera topics:')
    if not cameras and not unreadable:
        typer.echo('  (none)')
    for cam in cameras.values():
        span = (cam.last_ns - cam.first_ns) / 1e9
        hz = (cam.count - 1) / span if cam.count > 1 and span > 0 else None
        size = f'{cam.width}x{cam.height}' if cam.width else '?'
        flags = ' depth' if cam.is_depth else ''
        extra = f'  camera_info: {cam.camera_info_topic}' if cam.camera_info_topic else ''
        problem = f'  error: {cam.error}' if cam.error else ''
        rate = f'{fmt(hz, 1)} Hz'
        echo(
            f'  {cam.name}  {cam.msgtype}  {cam.count} msgs  {rate}  {size}  '
            f'{cam.encoding}{flags}{extra}{problem}'
        )
    for st in skipped:
        if st.name in unreadable:
            echo(f'  {st.name}  {st.msgtype}  {st.count} msgs  skipped: {st.reason}')
    others = [t for t in topics if t.name not in cameras]
    skipped_others = [st for st in skipped if st.name not in unreadable]
    if others or skipped_others:
        typer.echo('other topics:')
        for t in others:
            echo(f'  {t.name}  {t.msgtype}  {t.count} msgs')
        for st in skipped_others:
            echo(f'  {st.name}  {st.msgtype}  {st.count} msgs  skipped: {st.reason}')
    for warning in warnings:
        echo(f'replaybench: warning: {warning}', err=True)
