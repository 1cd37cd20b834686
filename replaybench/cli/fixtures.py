"""``replaybench fixtures``: write the synthetic fixture bags."""

from __future__ import annotations

import sys
from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import Annotated

import typer

from replaybench.cli._common import app, fail
from replaybench.cli.progress import FixtureProgress
from replaybench.errors import ReplaybenchError

__all__: list[str] = []


@app.command()
def fixtures(
    out: Annotated[Path, typer.Option('--out', '-o', help='Folder to write the bags into.')],
    frames: Annotated[int, typer.Option('--frames', min=1, help='Frames per camera.')] = 30,
    size: Annotated[
        str | None, typer.Option('--size', help='Image size WxH (320x240; 640x480 with --tags).')
    ] = None,
    ci: Annotated[
        bool,
        typer.Option(
            '--ci',
            help='Write only ci.mcap: 300 frames of 320x240 JPEG with ground truth, the bag '
            "README's CI example gates on (--frames and --size do not apply).",
        ),
    ] = False,
    masks: Annotated[
        bool,
        typer.Option(
            '--masks',
            help='Also write ground-truth label masks (mono8 class ids) on /ground_truth/labels, '
            "and live_masks.mcap (a segmentation node's masks recorded live).",
        ),
    ] = False,
    tags: Annotated[
        bool,
        typer.Option(
            '--tags',
            help='Write the AprilTag bags instead (tags.mcap, tags_fisheye.mcap, and '
            "live_tags.mcap: a tag node's outputs recorded live).",
        ),
    ] = False,
    stereo: Annotated[
        bool,
        typer.Option(
            '--stereo',
            help='Write only the stereo bags: stereo.mcap (rectified, image_rect) and '
            'stereo_raw.mcap (distorted, rotated, image_raw), 10 Hz mono8 pairs with CameraInfo '
            'and exact ground-truth disparity on /ground_truth/disparity.',
        ),
    ] = False,
    rig: Annotated[
        int | None,
        typer.Option(
            '--rig',
            help='Write only rig.mcap: N JPEG cameras (1 to 8) at 30 Hz with ground truth, '
            'hardware-synchronised stamps, the last camera starting 2 frames late.',
        ),
    ] = None,
    tracks: Annotated[
        bool,
        typer.Option(
            '--tracks',
            help='Write only tracks.mcap: 90 frames of one JPEG camera whose objects cross and '
            'pass behind a wall, truth boxes with ids (docs/tracking.md; --frames does not '
            'apply).',
        ),
    ] = False,
) -> None:
    """Generate the synthetic fixture bags (MCAP raw/jpeg, rosbag2 .db3, ROS 1 .bag, two cameras,
    and live_detections.mcap: a detector's outputs recorded live, logged after their images).

    Example: replaybench fixtures --out /tmp/bags --frames 300 --size 1920x1080
    """
    from replaybench.errors import UsageError
    from replaybench.fixtures import generate_fixtures

    if ci:
        from replaybench.fixtures.writer import write_ci_fixture

        typer.echo(str(write_ci_fixture(out)))
        return
    if sum((rig is not None, tags, stereo, tracks)) > 1:
        msg = '--rig, --tags, --stereo and --tracks write different bags: give one of them'
        raise fail(UsageError(msg))
    if size is None:
        size = '640x480' if tags else '320x240'
    try:
        w, _, h = size.lower().partition('x')
        if not (w.isdigit() and h.isdigit() and int(w) >= 32 and int(h) >= 32):
            msg = f'invalid --size {size!r}: use WxH with both at least 32, e.g. 640x480'
            raise UsageError(msg)
        if rig is not None:
            paths = [_write_rig(out, rig, frames, (int(w), int(h)))]
        elif tracks:
            paths = [_write_tracks(out, (int(w), int(h)))]
        elif stereo:
            paths = _write_stereo(out, frames, (int(w), int(h)))
        elif tags:
            from replaybench.fixtures.live_tasks import write_live_tag_fixture
            from replaybench.fixtures.tags import generate_tag_fixtures

            paths = generate_tag_fixtures(
                out, frames=frames, size=(int(w), int(h)), progress=FixtureProgress(sys.stderr)
            )
            # a tag node's outputs recorded live beside the tag bags
            paths.append(
                write_live_tag_fixture(
                    out, frames=frames, size=(int(w), int(h)), progress=FixtureProgress(sys.stderr)
                )
            )
        else:
            paths = generate_fixtures(
                out,
                frames=frames,
                size=(int(w), int(h)),
                progress=FixtureProgress(sys.stderr),
                masks=masks,
            )
    except ReplaybenchError as err:
        raise fail(err) from None
    for path in paths:
        typer.echo(str(path))


def _write_rig(out: Path, cameras: int, frames: int, size: tuple[int, int]) -> Path:
    """``rig.mcap`` in ``out`` (replacing it); a count or frames it cannot hold: UsageError."""
    from replaybench.errors import UsageError
    from replaybench.fixtures.rig import LATE_FRAMES, MAX_CAMERAS, RIG_FIXTURE, write_rig_mcap

    if not 1 <= cameras <= MAX_CAMERAS:
        msg = f'invalid --rig {cameras}: a rig holds 1 to {MAX_CAMERAS} cameras'
        raise UsageError(msg)
    if cameras > 1 and frames <= LATE_FRAMES:
        msg = f'--frames {frames} is too few for a rig: its last camera starts {LATE_FRAMES} late'
        raise UsageError(msg)
    out.mkdir(parents=True, exist_ok=True)
    target = out / RIG_FIXTURE
    target.unlink(missing_ok=True)
    progress = FixtureProgress(sys.stderr)

    def report(done: int) -> None:
        progress(RIG_FIXTURE, done, frames)

    return write_rig_mcap(target, frames, size, cameras, progress=report)


def _write_stereo(out: Path, frames: int, size: tuple[int, int]) -> list[Path]:
    """``stereo.mcap`` and ``stereo_raw.mcap`` in ``out`` (replacing them)."""
    from replaybench.fixtures.stereo import STEREO_FIXTURE, STEREO_RAW_FIXTURE, write_stereo_mcap

    out.mkdir(parents=True, exist_ok=True)
    progress = FixtureProgress(sys.stderr)
    paths = []
    for name, raw in ((STEREO_FIXTURE, False), (STEREO_RAW_FIXTURE, True)):
        target = out / name
        target.unlink(missing_ok=True)

        def report(done: int, name: str = name) -> None:
            progress(name, done, frames)

        paths.append(write_stereo_mcap(target, frames, size, raw=raw, progress=report))
    return paths


def _write_tracks(out: Path, size: tuple[int, int]) -> Path:
    """``tracks.mcap`` in ``out`` (replacing it)."""
    from replaybench.fixtures.tracks import TRACKS_BAG, TRACKS_FRAMES, write_tracks_mcap

    out.mkdir(parents=True, exist_ok=True)
    target = out / TRACKS_BAG
    target.unlink(missing_ok=True)
    progress = FixtureProgress(sys.stderr)

    def report(done: int) -> None:
        progress(TRACKS_BAG, done, TRACKS_FRAMES)

    return write_tracks_mcap(target, TRACKS_FRAMES, size, progress=report)
