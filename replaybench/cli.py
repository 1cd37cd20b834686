"""The ``replaybench`` command line: a thin layer over the library."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path  # noqa: TC003 - typer reads the annotations at run time
from typing import TYPE_CHECKING, Annotated, Any, TypeVar

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from replaybench._version import __version__
from replaybench.errors import ReplaybenchError, RunAborted
from replaybench.textsafe import visible, visible_lines

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from replaybench.replay.runner import RunConfig, RunOutcome
    from replaybench.results.stats import Summary

__all__ = ['app', 'main']

_Function = TypeVar('_Function', bound='Callable[..., Any]')

EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: Placeholders shown in help and usage lines, by parameter name; other parameters get one by
#: type (_metavar). Positional arguments are their name in capitals, singular when repeated.
_METAVARS = {
    'backend': 'NAME',
    'out': 'DIR',
    'rate': 'RATE',
    'topic': 'TOPIC',
    'ground_truth': 'TOPIC',
    'recorded_topic': 'TOPIC',
    'ground_truth_image_topic': 'TOPIC',
    'ground_truth_match': 'stamp|seq',
    'model_family': 'FAMILY',
    'labels': 'coco|PATH',
    'engine': 'auto|ort|torch',
    'precision': 'fp32|tf32|fp16',
    'detections_format': 'mcap|rosbag2',
    'start': 'S',
    'duration': 'S',
    'size': 'WxH',
    'fail_if': 'CONDITION',
    'param': 'BACKEND.KEY=V,...',
    'address': 'HOST:PORT',
    'max_drop': 'FRACTION',
    'p99_ms': 'MS',
    'min_hz': 'HZ',
    'max_hz': 'HZ',
}
_TYPE_METAVARS = {'Path': 'PATH', 'int': 'N', 'float': 'X', 'str': 'TEXT'}
#: click's UsageError (bad option, bad value, missing argument), found without importing the
#: click that typer vendors by its private name
_USAGE_ERROR: type[Exception] = next(
    c for c in typer.BadParameter.__mro__ if c.__name__ == 'UsageError'
)


def _metavar(name: str, bare_type: str) -> str:
    known = _METAVARS.get(name)
    if known is not None:
        return known
    return _TYPE_METAVARS.get(bare_type.removeprefix('list[').removesuffix(']'), 'VALUE')


class _Argument(TyperArgument):
    """A positional argument shown by its placeholder alone: ``BAG...``, not ``{bags}...``
    followed by ``<list[Path]>``."""

    def _usage_display_name(self) -> str:
        name = self.display_name_raw + ('...' if self.nargs != 1 else '')
        return name if self.required else f'[{name}]'

    def _rich_display_name(self) -> str:
        return self.display_name_raw + ('...' if self.nargs != 1 else '')

    def display_type_rich(self, ctx: Any) -> str | None:  # noqa: ARG002  click's signature
        return None


class _Option(TyperOption):
    """An option whose bad value is named in the error, next to what was wrong with it."""

    def process_value(self, ctx: Any, value: Any) -> Any:
        try:
            return super().process_value(ctx, value)
        except typer.BadParameter as err:
            if value is not None and repr(value) not in err.message:
                err.message = f'{value!r}: {err.message}'
            raise


class _Command(TyperCommand):
    """A command whose help shows placeholders people read (``PATH``, ``NAME``, ``N``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.help:
            # examples are copied to a shell: click must not wrap them ('\b' keeps a paragraph)
            self.help = self.help.replace('\n\nExample:', '\n\n\b\nExample:')
        for param in self.params:
            name = param.name or ''
            if isinstance(param, TyperArgument):
                param.__class__ = _Argument
                if param.metavar is None:
                    singular = name.removesuffix('s') if param.nargs != 1 else name
                    param.metavar = singular.upper()
            elif isinstance(param, TyperOption):
                param.__class__ = _Option
                if param.metavar is None and not param.is_flag:
                    param.metavar = _metavar(name, param.bare_type())


class _Group(TyperGroup):
    """The command group: a usage error is two lines on stderr, what is wrong (naming the value)
    and the usage line, exit status 2; not click's four."""

    def main(  # type: ignore[override]
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            code = super().main(args, prog_name, complete_var, False, **extra)
        except _USAGE_ERROR as err:
            if type(err).__name__ == 'NoArgsIsHelpError':  # bare `replaybench`: the help
                getattr(err, 'show', lambda: None)()
                sys.exit(EXIT_USAGE)
            ctx = getattr(err, 'ctx', None)
            describe = getattr(err, 'format_message', None)
            message = describe() if callable(describe) else str(err)
            _echo(f'replaybench: error: {message}', err=True)
            if ctx is not None:
                usage = ctx.get_usage().strip()
                _echo(f'{usage}  (-h for help)', err=True)
            sys.exit(EXIT_USAGE)
        except typer.Abort:
            sys.stderr.write('replaybench: aborted\n')
            sys.exit(EXIT_FAILURE)
        sys.exit(code if isinstance(code, int) else 0)


class _App(typer.Typer):
    """``typer.Typer`` whose commands are ``_Command``s."""

    def command(self, *args: Any, **kwargs: Any) -> Callable[[_Function], _Function]:
        kwargs.setdefault('cls', _Command)
        return super().command(*args, **kwargs)


app = _App(
    cls=_Group,
    name='replaybench',
    help='Replay camera logs through detectors and measure latency, FPS and accuracy.\n\n'
    'Example: replaybench run bag.mcap --backend hsv --backend null',
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
    context_settings={'help_option_names': ['-h', '--help']},
)


def _echo(text: str, *, err: bool = False) -> None:
    """One line of output with control characters shown as escapes: names from a bag may
    hold terminal control sequences (``replaybench.textsafe``)."""
    typer.echo(visible(text), err=err)


class _Debug:
    """``--debug``: set by the root callback on every invocation, read by ``_fail``."""

    on = False


def _fail(err: ReplaybenchError) -> typer.Exit:
    """The error's one line on stderr (after, with ``--debug``, the traceback of the error and
    of the exceptions it was raised from); the exit to raise."""
    if _Debug.on:
        import traceback

        sys.stderr.write(visible_lines(''.join(traceback.format_exception(err))))
    _echo(f'replaybench: error: {err}', err=True)
    return typer.Exit(err.exit_code)


def _version(value: bool) -> None:
    if value:
        typer.echo(f'replaybench {__version__}')
        raise typer.Exit


@app.callback()
def _root(
    version: Annotated[  # noqa: ARG001  --version is handled by its eager callback
        bool, typer.Option('--version', callback=_version, is_eager=True, help='Print the version.')
    ] = False,
    debug: Annotated[
        bool,
        typer.Option(
            '--debug',
            help='On an error, print the traceback of its cause before the one-line message.',
        ),
    ] = False,
) -> None:
    """Replay camera logs through detectors and measure latency, FPS and accuracy.

    Example: replaybench run bag.mcap --backend hsv --backend null
    """
    _Debug.on = debug


class _Progress:
    """A one-line progress bar on stderr, drawn only when stderr is a terminal."""

    def __init__(self) -> None:
        self.enabled = sys.stderr.isatty()
        self.last = -1

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled or total <= 0:
            return
        pct = min(100, done * 100 // total)
        if pct == self.last and done != total:
            return
        self.last = pct
        bar = '#' * (pct // 4) + '.' * (25 - pct // 4)
        sys.stderr.write(f'\r[{bar}] {pct:3d}% {done}/{total} frames')
        if done >= total:
            sys.stderr.write('\n')
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled and self.last >= 0:
            sys.stderr.write('\n')

    def notice(self, line: str) -> None:
        """A line for a person (the hashing of a large input), on its own line of stderr."""
        if self.enabled and 0 <= self.last < 100:
            sys.stderr.write('\n')
        _echo(line, err=True)


class _FixtureProgress:
    """Progress of ``replaybench fixtures`` on ``stream``: on a terminal one line per bag,
    redrawn as its frames are written; elsewhere (a log, a pipe) a line every ``every_s``
    seconds while the generation lasts, none for a short one."""

    def __init__(
        self,
        stream: Any,
        *,
        every_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stream = stream
        self.terminal = bool(getattr(stream, 'isatty', lambda: False)())
        self.every_s = every_s
        self.clock = clock
        self.began = self.last_line = clock()
        self.last_draw = -1.0

    def __call__(self, name: str, done: int, total: int) -> None:
        now = self.clock()
        text = f'replaybench: writing {visible(name)}: {done}/{total} frames'
        if self.terminal:
            if done == total or now - self.last_draw >= 0.1:
                self.last_draw = now
                self.stream.write(f'\r{text}' + ('\n' if done == total else ''))
                self.stream.flush()
        elif now - self.last_line >= self.every_s:
            self.last_line = now
            self.stream.write(f'{text} ({now - self.began:.0f} s)\n')
            self.stream.flush()


def _fmt(value: float | None, digits: int = 2) -> str:
    return '-' if value is None else f'{value:.{digits}f}'


def _print_summary(summaries: list[Summary]) -> None:
    header = (
        'backend',
        'topic',
        'frames',
        'drop',
        'skip',
        'fps',
        'p50 ms',
        'p99 ms',
        'det/frame',
        'P@.5',
        'R@.5',
        'mAP@.5',
        'private MiB',
    )
    rows = []
    for s in summaries:
        acc = s.accuracy or {}
        # private (anonymous) memory, not the RSS that counts the memory-mapped input
        private = (s.resources or {}).get('private_mb_peak')
        rows.append(
            (
                visible(s.backend),
                visible(s.topic),
                str(s.measured),
                str(s.dropped),
                str(s.skipped),
                _fmt(s.throughput_fps, 1),
                _fmt(s.latency_ms_p50),
                _fmt(s.latency_ms_p99),
                _fmt(s.detections_per_frame),
                _fmt(acc.get('precision50'), 3),
                _fmt(acc.get('recall50'), 3),
                _fmt(acc.get('map50'), 3),
                _fmt(private, 0),
            )
        )
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(header)]
    for row in (header, *rows):
        typer.echo(
            '  '.join(
                c.ljust(w) if i < 2 else c.rjust(w)
                for i, (c, w) in enumerate(zip(row, widths, strict=True))
            )
        )


@app.command()
def run(
    bags: Annotated[
        list[Path],
        typer.Argument(
            help='Bag files or rosbag2 folders, replayed one after another.', show_default=False
        ),
    ],
    backend: Annotated[
        list[str],
        typer.Option(
            '--backend',
            '-b',
            help='Backend to run (repeat for several; see `replaybench backends`).',
        ),
    ] = [],  # noqa: B006
    out: Annotated[
        Path | None,
        typer.Option(
            '--out', '-o', help='Run folder (default: a new folder under ./replaybench-runs/).'
        ),
    ] = None,
    force: Annotated[
        bool,
        typer.Option(
            '--force', help='Replace the run folder --out, once the new run has finished.'
        ),
    ] = False,
    rate: Annotated[
        str,
        typer.Option('--rate', help='max, recorded, 2x / 0.5x (scaled recorded), or 30hz (fixed).'),
    ] = 'max',
    queue_depth: Annotated[
        int,
        typer.Option(
            '--queue-depth', min=1, help='Per-topic queue depth in timed modes (newest kept).'
        ),
    ] = 1,
    warmup: Annotated[
        int | None,
        typer.Option(
            '--warmup',
            min=0,
            help='Warm-up frames per backend and topic (default 10, at most a tenth of the topic).',
        ),
    ] = None,
    threads: Annotated[
        int | None,
        typer.Option('--threads', min=1, help='CPU threads for OpenCV and the backends.'),
    ] = None,
    max_frames: Annotated[
        int | None, typer.Option('--max-frames', min=1, help='At most N frames of each topic.')
    ] = None,
    start: Annotated[
        float | None, typer.Option('--start', min=0.0, help='Skip the first S seconds of each bag.')
    ] = None,
    duration: Annotated[
        float | None, typer.Option('--duration', min=0.0, help='Replay only S seconds.')
    ] = None,
    topic: Annotated[
        list[str],
        typer.Option(
            '--topic',
            '-t',
            help='Image topic to replay (repeat; default: every non-depth image topic).',
        ),
    ] = [],  # noqa: B006
    ground_truth: Annotated[
        str | None,
        typer.Option(
            '--ground-truth',
            help='Detection2DArray topic holding ground truth '
            '(default: /ground_truth/detections when present).',
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(
            '--config', help='Backend configuration file (TOML), e.g. hsv colour classes.'
        ),
    ] = None,
    model: Annotated[
        Path | None,
        typer.Option('--model', help='ONNX model for the DNN backends (default: the bundled one).'),
    ] = None,
    model_family: Annotated[
        str | None,
        typer.Option('--model-family', help='Output layout: yolox, yolov5, yolov8 or nms.'),
    ] = None,
    labels: Annotated[
        str | None,
        typer.Option('--labels', help='Class names: coco, or a file with one name per line.'),
    ] = None,
    conf: Annotated[
        float | None,
        typer.Option('--conf', min=0.0, max=1.0, help='Score threshold for DNN detections.'),
    ] = None,
    iou: Annotated[
        float | None, typer.Option('--iou', min=0.0, max=1.0, help='IoU threshold for NMS.')
    ] = None,
    device: Annotated[int, typer.Option('--device', min=0, help='GPU index.')] = 0,
    engine: Annotated[
        str, typer.Option('--engine', help='GPU engine for the cuda backend: auto, ort or torch.')
    ] = 'auto',
    precision: Annotated[
        str,
        typer.Option('--precision', help='fp32 (TF32 off), tf32 or fp16 (GPU backends).'),
    ] = 'fp32',
    recorded_topic: Annotated[
        str | None,
        typer.Option(
            '--recorded-topic',
            help='Detection2DArray topic scored by the `recorded` backend '
            '(detections made on the robot).',
        ),
    ] = None,
    ground_truth_file: Annotated[
        Path | None,
        typer.Option(
            '--ground-truth-file',
            help='COCO JSON or CVAT XML ground truth, instead of a topic (docs/ground-truth.md).',
        ),
    ] = None,
    ground_truth_match: Annotated[
        str,
        typer.Option(
            '--ground-truth-match',
            help='Match --ground-truth-file to frames by stamp (header stamp) or seq (index '
            'of the image within its topic).',
        ),
    ] = 'stamp',
    ground_truth_image_topic: Annotated[
        str | None,
        typer.Option(
            '--ground-truth-image-topic',
            help='The image topic --ground-truth-file annotates (needed with several topics).',
        ),
    ] = None,
    ground_truth_seq_offset: Annotated[
        int,
        typer.Option(
            '--ground-truth-seq-offset',
            help='Subtracted from image ids / frame numbers with --ground-truth-match seq '
            '(1 for COCO files whose ids start at 1).',
        ),
    ] = 0,
    annotations: Annotated[
        bool,
        typer.Option(
            '--annotations',
            help='Also write Foxglove ImageAnnotations (boxes and labels) into detections.mcap.',
        ),
    ] = False,
    copy_images: Annotated[
        bool,
        typer.Option(
            '--copy-images',
            help='Copy the replayed image messages into detections.mcap (docs/foxglove.md).',
        ),
    ] = False,
    detections_format: Annotated[
        str,
        typer.Option(
            '--format',
            help='mcap, or rosbag2: also write metadata.yaml, so that the run folder opens as a '
            'rosbag2 bag (docs/foxglove.md).',
        ),
    ] = 'mcap',
    no_report: Annotated[bool, typer.Option('--no-report', help='Skip report.html.')] = False,
    no_hash: Annotated[
        bool,
        typer.Option(
            '--no-hash',
            help="Do not compute the inputs' sha256 (run.json records null; compare cannot "
            'check the inputs).',
        ),
    ] = False,
) -> None:
    """Replay bags through backends and write detections, CSVs, run.json and a report.

    Example: replaybench run fixtures/bags/rgb8_raw.mcap --backend hsv --backend null --out runs/a
    """
    from replaybench.app.run import run_config
    from replaybench.replay.runner import new_run_dir

    progress = _Progress()
    try:
        settings = run_config(
            bags,
            backends=backend,
            out=out if out is not None else new_run_dir(),
            force=force,
            rate=rate,
            queue_depth=queue_depth,
            warmup=warmup,
            threads=threads,
            max_frames=max_frames,
            start=start,
            duration=duration,
            topics=topic,
            ground_truth=ground_truth,
            config=config,
            model=model,
            model_family=model_family,
            labels=labels,
            conf=conf,
            iou=iou,
            device=device,
            engine=engine,
            precision=precision,
            recorded_topic=recorded_topic,
            ground_truth_file=ground_truth_file,
            ground_truth_match=ground_truth_match,
            ground_truth_image_topic=ground_truth_image_topic,
            ground_truth_seq_offset=ground_truth_seq_offset,
            annotations=annotations,
            copy_images=copy_images,
            detections_format=detections_format,
            report=not no_report,
            hash_inputs=not no_hash,
            command=['replaybench', *sys.argv[1:]],
        )
        outcome = _run_until_stopped(settings, progress)
    except ReplaybenchError as err:
        progress.close()
        raise _fail(err) from None
    code = _show_run(outcome)
    if code:
        raise typer.Exit(code)


def _run_until_stopped(config: RunConfig, progress: _Progress) -> RunOutcome:
    """The run, Ctrl-C and SIGTERM ending it as interrupted (a second one: at once)."""
    from replaybench.app.run import run_benchmark
    from replaybench.app.signals import stop_on_signals

    token = threading.Event()
    with stop_on_signals(token):
        return run_benchmark(config, progress=progress, stop=token, notice=progress.notice)


def _show_run(outcome: RunOutcome) -> int:
    """Print a finished run (the table, its warnings, the folder); its exit status."""
    from replaybench.backends.gpu import engine_lines

    _print_summary(outcome.summaries)
    for s in outcome.summaries:  # stability of each (backend, topic): intervals need not hold
        where = f'{s.backend} {s.topic}'
        for warning in s.warnings:
            _echo(f'replaybench: warning: {where}: {warning}', err=True)
    for warning in (w for inp in outcome.run.inputs for w in inp.warnings):
        _echo(f'replaybench: warning: {warning}', err=True)
    for reason, count in outcome.run.skipped.items():
        _echo(f'replaybench: warning: skipped {count} message(s): {reason}', err=True)
    for warning in outcome.run.warnings:
        _echo(f'replaybench: warning: {warning}', err=True)
    for entry in outcome.run.backends:
        facts = entry.info
        if facts.get('nonfinite_dropped'):
            _echo(
                f'replaybench: warning: {entry.name}: left out {facts["nonfinite_dropped"]} '
                f'candidate(s) with NaN or inf model outputs in {facts["nonfinite_frames"]} '
                'frame(s)',
                err=True,
            )
    for line in engine_lines(outcome.run):
        _echo(line)
    assert outcome.run_dir is not None  # the command line always writes a folder
    report = outcome.run_dir / 'report.html'
    _echo(f'Run folder: {outcome.run_dir}')
    if report.exists():
        _echo(f'Report: {report}')
    if outcome.status == 'interrupted':
        typer.echo('replaybench: interrupted: outputs hold the frames done so far', err=True)
        return EXIT_INTERRUPTED
    if outcome.status == 'partial':
        failed = '; '.join(
            f'backend {b.name!r} raised on input {b.error.input} {b.error.topic} '
            f'seq {b.error.seq}: {b.error.message}'
            for b in outcome.run.backends
            if b.status == 'failed' and b.error is not None
        )
        _echo(
            f'replaybench: error: {failed}; it was stopped there and the other backends '
            'finished (run.json status partial)',
            err=True,
        )
        return EXIT_FAILURE
    return 0


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
        raise _fail(err) from None
    first = min((t.first_ns for t in topics), default=0)
    last = max((t.last_ns for t in topics), default=0)
    total = sum(t.count for t in topics) + sum(t.count for t in skipped)
    _echo(f'path:       {bag}')
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
        rate = f'{_fmt(hz, 1)} Hz'
        _echo(
            f'  {cam.name}  {cam.msgtype}  {cam.count} msgs  {rate}  {size}  '
            f'{cam.encoding}{flags}{extra}{problem}'
        )
    for st in skipped:
        if st.name in unreadable:
            _echo(f'  {st.name}  {st.msgtype}  {st.count} msgs  skipped: {st.reason}')
    others = [t for t in topics if t.name not in cameras]
    skipped_others = [st for st in skipped if st.name not in unreadable]
    if others or skipped_others:
        typer.echo('other topics:')
        for t in others:
            _echo(f'  {t.name}  {t.msgtype}  {t.count} msgs')
        for st in skipped_others:
            _echo(f'  {st.name}  {st.msgtype}  {st.count} msgs  skipped: {st.reason}')
    for warning in warnings:
        _echo(f'replaybench: warning: {warning}', err=True)


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
        _echo(line)
    if not found.ok:
        raise typer.Exit(1)


@app.command()
def fixtures(
    out: Annotated[Path, typer.Option('--out', '-o', help='Folder to write the bags into.')],
    frames: Annotated[int, typer.Option('--frames', min=1, help='Frames per camera.')] = 30,
    size: Annotated[str, typer.Option('--size', help='Image size WxH.')] = '320x240',
) -> None:
    """Generate the synthetic fixture bags (MCAP raw/jpeg, rosbag2 .db3, ROS 1 .bag, two cameras).

    Example: replaybench fixtures --out /tmp/bags --frames 300 --size 1920x1080
    """
    from replaybench.errors import UsageError
    from replaybench.fixtures import generate_fixtures

    try:
        w, _, h = size.lower().partition('x')
        if not (w.isdigit() and h.isdigit() and int(w) >= 32 and int(h) >= 32):
            msg = f'invalid --size {size!r}: use WxH with both at least 32, e.g. 640x480'
            raise UsageError(msg)
        paths = generate_fixtures(
            out, frames=frames, size=(int(w), int(h)), progress=_FixtureProgress(sys.stderr)
        )
    except ReplaybenchError as err:
        raise _fail(err) from None
    for path in paths:
        typer.echo(str(path))


@app.command()
def peak(
    bag: Annotated[Path, typer.Argument(help='Bag file or rosbag2 folder.', show_default=False)],
    backend: Annotated[str, typer.Option('--backend', '-b', help='Backend to sweep.')],
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
    topic: Annotated[
        list[str], typer.Option('--topic', '-t', help='Image topic(s) to replay.')
    ] = [],  # noqa: B006
    threads: Annotated[
        int | None, typer.Option('--threads', min=1, help='CPU threads for OpenCV and backends.')
    ] = None,
    config: Annotated[Path | None, typer.Option('--config', help='Backend TOML file.')] = None,
    model: Annotated[Path | None, typer.Option('--model', help='ONNX model.')] = None,
    model_family: Annotated[str | None, typer.Option('--model-family', help='Layout.')] = None,
    labels: Annotated[str | None, typer.Option('--labels', help='Class names.')] = None,
    conf: Annotated[float | None, typer.Option('--conf', min=0.0, max=1.0)] = None,
    iou: Annotated[float | None, typer.Option('--iou', min=0.0, max=1.0)] = None,
    device: Annotated[int, typer.Option('--device', min=0, help='GPU index.')] = 0,
    engine: Annotated[str, typer.Option('--engine', help='auto, ort or torch.')] = 'auto',
    precision: Annotated[
        str, typer.Option('--precision', help='fp32 (TF32 off), tf32 or fp16.')
    ] = 'fp32',
    no_report: Annotated[bool, typer.Option('--no-report', help='Skip peak.html.')] = False,
) -> None:
    """Find the highest replay rate a backend sustains without dropping frames.

    Example: replaybench peak fixtures/bags/jpeg.mcap --backend hsv --max-drop 0.05 --out runs/peak
    """
    from replaybench.app.peak import peak_config, run_peak
    from replaybench.app.signals import stop_on_signals
    from replaybench.replay.runner import new_run_dir

    def show(trial: Any) -> None:
        verdict = 'pass' if trial.ok else 'fail'
        typer.echo(
            f'{trial.rate_hz:g} Hz: dropped {trial.dropped}/{trial.frames}, '
            f'p99 {_fmt(trial.p99_ms)} ms, {verdict}',
            err=True,
        )

    token = threading.Event()
    try:
        settings = peak_config(
            bag,
            backend=backend,
            out=out if out is not None else new_run_dir(),
            max_drop=max_drop,
            p99_ms=p99_ms,
            trial_frames=trial_frames,
            min_hz=min_hz,
            max_hz=max_hz,
            refine_steps=refine_steps,
            topics=topic,
            threads=threads,
            force=force,
            report=not no_report,
            command=['replaybench', *sys.argv[1:]],
            config=config,
            model=model,
            model_family=model_family,
            labels=labels,
            conf=conf,
            iou=iou,
            device=device,
            engine=engine,
            precision=precision,
        )
        with stop_on_signals(token):
            result = run_peak(settings, progress=show, stop=token)
    except ReplaybenchError as err:
        raise _fail(err) from None
    folder = settings.out
    assert folder is not None  # the command line always writes a folder
    typer.echo(f'{"rate Hz":>10}  {"frames":>6}  {"dropped":>7}  {"p99 ms":>8}  verdict')
    for t in result.trials:
        verdict = 'pass' if t.ok else 'fail'
        typer.echo(
            f'{t.rate_hz:>10.3f}  {t.frames:>6}  {t.dropped:>7}  {_fmt(t.p99_ms):>8}  {verdict}'
        )
    if result.peak_hz is None:
        typer.echo(f'{backend}: no rate tried met the limits')
    else:
        typer.echo(f'{backend}: peak sustainable rate {result.peak_hz:.3f} Hz')
    for warning in result.warnings:
        _echo(f'replaybench: warning: {warning}', err=True)
    _echo(f'Peak folder: {folder}')
    if (folder / 'peak.html').exists():
        _echo(f'Report: {folder / "peak.html"}')
    if result.status == 'interrupted':
        raise typer.Exit(EXIT_INTERRUPTED)


@app.command()
def sweep(
    bags: Annotated[
        list[Path],
        typer.Argument(
            help='Bags or rosbag2 folders, at the same path on every Ray node.', show_default=False
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            '--out', '-o', help='Sweep folder; running the same command again resumes it.'
        ),
    ],
    backend: Annotated[
        list[str], typer.Option('--backend', '-b', help='Backend to sweep (repeat for several).')
    ] = [],  # noqa: B006
    param: Annotated[
        list[str],
        typer.Option(
            '--param',
            help='Grid of one backend option: BACKEND.KEY=V1,V2,... (repeat; one cell per '
            'combination), e.g. hsv.min_area=50,100,200.',
        ),
    ] = [],  # noqa: B006
    address: Annotated[
        str | None,
        typer.Option(
            '--address', help='Ray cluster to join (host:port); default: a local Ray instance.'
        ),
    ] = None,
    pack: Annotated[
        bool,
        typer.Option(
            '--pack', help='Fill every CPU instead of one timed cell per node (accuracy only).'
        ),
    ] = False,
    max_retries: Annotated[
        int,
        typer.Option(
            '--max-retries', min=0, help='Ray re-runs of a cell whose worker or node died.'
        ),
    ] = 3,
    rate: Annotated[
        str,
        typer.Option('--rate', help='max, recorded, 2x / 0.5x (scaled recorded), or 30hz (fixed).'),
    ] = 'max',
    queue_depth: Annotated[
        int, typer.Option('--queue-depth', min=1, help='Per-topic queue depth in timed modes.')
    ] = 1,
    warmup: Annotated[
        int | None, typer.Option('--warmup', min=0, help='Warm-up frames per backend and topic.')
    ] = None,
    threads: Annotated[
        int | None, typer.Option('--threads', min=1, help='CPU threads for OpenCV and backends.')
    ] = None,
    max_frames: Annotated[
        int | None, typer.Option('--max-frames', min=1, help='At most N frames of each topic.')
    ] = None,
    start: Annotated[
        float | None, typer.Option('--start', min=0.0, help='Skip the first S seconds of each bag.')
    ] = None,
    duration: Annotated[
        float | None, typer.Option('--duration', min=0.0, help='Replay only S seconds.')
    ] = None,
    topic: Annotated[
        list[str], typer.Option('--topic', '-t', help='Image topic(s) to replay.')
    ] = [],  # noqa: B006
    ground_truth: Annotated[
        str | None, typer.Option('--ground-truth', help='Detection2DArray ground-truth topic.')
    ] = None,
    config: Annotated[Path | None, typer.Option('--config', help='Backend TOML file.')] = None,
    model: Annotated[Path | None, typer.Option('--model', help='ONNX model.')] = None,
    model_family: Annotated[str | None, typer.Option('--model-family', help='Layout.')] = None,
    labels: Annotated[str | None, typer.Option('--labels', help='Class names.')] = None,
    conf: Annotated[float | None, typer.Option('--conf', min=0.0, max=1.0)] = None,
    iou: Annotated[float | None, typer.Option('--iou', min=0.0, max=1.0)] = None,
    engine: Annotated[str, typer.Option('--engine', help='auto, ort or torch.')] = 'auto',
    precision: Annotated[str, typer.Option('--precision', help='GPU precision.')] = 'fp32',
    recorded_topic: Annotated[
        str | None, typer.Option('--recorded-topic', help='Topic for the `recorded` backend.')
    ] = None,
    annotations: Annotated[
        bool, typer.Option('--annotations', help='Foxglove ImageAnnotations too.')
    ] = False,
    copy_images: Annotated[
        bool, typer.Option('--copy-images', help='Copy the images into detections.mcap.')
    ] = False,
    no_report: Annotated[
        bool, typer.Option('--no-report', help="Skip each cell's report.html.")
    ] = False,
) -> None:
    """Run every bag x backend x --param combination as one run, on a Ray cluster (docs/sweep.md).

    Example: replaybench sweep fixtures/bags/*.mcap --backend hsv --backend null --out sweeps/s1
    """
    from replaybench.app.signals import stop_on_signals
    from replaybench.app.sweep import progress_bar, result_lines, run_sweep, sweep_config

    bar = progress_bar(sys.stderr)
    token = threading.Event()
    try:
        settings = sweep_config(
            bags,
            backends=backend,
            out=out,
            params=param,
            address=address,
            pack=pack,
            max_retries=max_retries,
            rate=rate,
            queue_depth=queue_depth,
            warmup=warmup,
            threads=threads,
            max_frames=max_frames,
            start=start,
            duration=duration,
            topics=topic,
            ground_truth=ground_truth,
            config=config,
            model=model,
            model_family=model_family,
            labels=labels,
            conf=conf,
            iou=iou,
            engine=engine,
            precision=precision,
            recorded_topic=recorded_topic,
            annotations=annotations,
            copy_images=copy_images,
            report=not no_report,
            command=['replaybench', *sys.argv[1:]],
        )
        with stop_on_signals(token):
            result = run_sweep(settings, progress=bar, stop=token)
    except ReplaybenchError as err:
        raise _fail(err) from None
    finally:
        if bar is not None:
            bar.close()
    lines, problems = result_lines(result)
    for line in lines:
        _echo(line)
    for line in problems:
        _echo(line, err=True)
    raise typer.Exit(result.exit_code)


@app.command()
def compare(
    run_dirs: Annotated[
        list[Path],
        typer.Argument(help='Run folders; the first is the baseline.', show_default=False),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            '--out',
            '-o',
            help='Also write comparison.html/.csv/.json into this folder (default: print only).',
        ),
    ] = None,
    fail_if: Annotated[
        list[str],
        typer.Option(
            '--fail-if',
            help='Gate condition, e.g. "p99_ms > +10%" or "map50 < -0.02" (repeat).',
        ),
    ] = [],  # noqa: B006
    strict: Annotated[
        bool, typer.Option('--strict', help='Judge conditions on the point estimate, not the CI.')
    ] = False,
    allow_inconclusive: Annotated[
        bool,
        typer.Option(
            '--allow-inconclusive',
            help='Exit 0, not 3, when no condition failed but the data could not decide one.',
        ),
    ] = False,
) -> None:
    """Compare runs across backends, machines or GPUs, with confidence intervals and a CI gate.

    Prints the table on stdout; with --out, also writes comparison.html, .csv and .json there.

    Exit status: 0 passed, 1 a condition failed, 2 bad input, 3 a condition inconclusive.

    Example: replaybench compare runs/main runs/branch --fail-if "p99_ms > +10%"
    """
    from replaybench.app.compare import compare_config, compare_lines, run_compare

    try:
        settings = compare_config(
            run_dirs,
            fail_if=fail_if,
            strict=strict,
            allow_inconclusive=allow_inconclusive,
            out=out,
        )
        outcome = run_compare(settings)
    except ReplaybenchError as err:
        raise _fail(err) from None
    for to_stderr, line in compare_lines(outcome):
        _echo(line, err=to_stderr)
    raise typer.Exit(outcome.exit_code)


@app.command()
def report(
    run_dir: Annotated[
        Path, typer.Argument(help='A run folder written by `replaybench run`.', show_default=False)
    ],
) -> None:
    """Render report.html again from a run folder (run.json, frames.csv, samples/).

    Example: replaybench report replaybench-runs/20261122-101500
    """
    from replaybench.report import render_report

    try:
        path = render_report(run_dir)
    except ReplaybenchError as err:
        raise _fail(err) from None
    _echo(f'Report: {path}')


def main() -> None:
    """Console-script entry point."""
    try:
        app()
    except KeyboardInterrupt:
        sys.stderr.write('replaybench: interrupted\n')
        sys.exit(EXIT_INTERRUPTED)
    except RunAborted:
        sys.stderr.write('replaybench: interrupted again: stopped without finishing the outputs\n')
        sys.exit(EXIT_INTERRUPTED)


if __name__ == '__main__':
    main()
