"""The prepared GPU check (benchmarks/gpu_check.sh; docs/gpu.md, "The GPU check").

One command for a bare machine with an NVIDIA GPU and no package registry: installs the carried
wheels into a target folder, writes its inputs with the fixture writer, then runs each step with
its own time limit, one after the other: nvidia-smi, the versions of the stack,
``replaybench doctor`` and ``backends``, runs of ``hsv`` / ``hsv-cuda``, ``onnx-cpu`` and
``cuda --engine torch`` (fp32, fp16; the bundled model and YOLOX-Nano; ``--rate max``; each DNN
run holds ``onnx-cpu`` beside ``cuda``, so run.json's ``agreement`` compares them),
``cuda-stereo --engine torch`` beside ``onnx-stereo`` on the stereo fixture (run.json's
``stereo_agreement``: the GPU disparity against the CPU one; EPE and bad-2 against the truth),
``cuda --engine torch`` beside ``onnx-seg`` with the bundled segmentation model on JPEG
frames with truth masks (mIoU and pixel accuracy of each), ``cuda`` fp16 on the four-camera
rig fixture with ``--pipelines shared`` and ``per-topic``
(four instances sharing one GPU: run.json's ``rig`` section, per-camera and rig rows),
``cuda --engine ort``, ``replaybench compare``, a ``peak`` search for ``cuda``,
``pytest tests/backends/gpu -rs``, one Ray sweep cell where Ray is installed, and the summary.

A step that fails or runs past its limit is logged with its exit status and the next one runs.
Everything printed (``check.log``, one log per step), ``steps.json``, the summary and the run
folders' JSON and CSV files are packed into ``gpu-check.tar.gz`` in ``--out`` ($OUT by default),
with copies of ``check.log``, ``steps.json`` and ``summary.md`` beside it: four files.

``--dry-run`` is the same script on a machine without a GPU: small inputs, no wheels, each GPU
step replaced by its CPU counterpart (``hsv`` beside ``null`` for ``hsv`` beside ``hsv-cuda``,
``onnx-cpu`` alone for ``onnx-cpu`` beside ``cuda``, ``onnx-stereo`` alone for it beside
``cuda-stereo``, ``onnx-seg`` alone for it beside ``cuda``, ``hsv`` for ``cuda`` on the
rig, ``peak`` of ``null``) or skipped with the
reason. ``--fail STEP`` and ``--hang STEP`` replace a step's command with one that fails or that
outlasts its limit (2 s), so the test of the script can show both are logged and the rest runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ['ARCHIVE', 'ARCHIVE_LIMIT', 'ON_GPU_MACHINE', 'Step', 'main', 'plan']

REPO = Path(__file__).resolve().parents[1]
ARCHIVE = 'gpu-check.tar.gz'
#: what comes back from the GPU machine: one file of at most 16 MiB
ARCHIVE_LIMIT = 16 * 2**20
#: the issue's budget for the steps (about 6 minutes; the whole call must end within 480 s)
DEFAULT_BUDGET_S = 400.0
HANG_TIMEOUT_S = 2.0
#: copied into --out beside the archive (at most 8 files come back from a GPU machine)
RETURNED = ('check.log', 'steps.json', 'summary.md')
#: replaybench's core dependencies the GPU machine's python3 already has (its package list, Nov
#: 2026); every other one is a pinned wheel of `make gpu-wheels` (tests/test_gpu_check.py)
ON_GPU_MACHINE = frozenset(
    {'numpy', 'opencv-python-headless', 'typer', 'protobuf', 'onnxruntime', 'threadpoolctl'}
)
RAY_MISSING = (
    'ray is not installed: its wheel (ray 2.60.0, cp312 manylinux2014 x86_64) is 75.6 MiB, over '
    'the 64 MiB the working tree may carry to the GPU machine'
)
VERSIONS = """
import importlib, importlib.util
for name in ('numpy', 'cv2', 'torch', 'cupy', 'onnxruntime', 'onnx', 'onnx2torch', 'mcap',
             'rosbags', 'ray', 'tensorrt', 'pynvml'):
    if importlib.util.find_spec(name) is None:
        print(name, 'not installed')
        continue
    try:
        module = importlib.import_module(name)
    except Exception as exc:
        print(name, 'does not import:', type(exc).__name__, exc)
        continue
    line = [name, str(getattr(module, '__version__', '?')), getattr(module, '__file__', '')]
    if name == 'torch':
        line += ['cuda', str(module.version.cuda), 'available', str(module.cuda.is_available())]
    if name == 'onnxruntime':
        line += ['providers', ','.join(module.get_available_providers())]
    print(*line)
"""


@dataclass(frozen=True)
class Step:
    """One step: its command on a GPU machine, its limit, and what a dry run does with it."""

    name: str
    argv: tuple[str, ...]
    timeout_s: float
    #: needs a GPU: a dry run runs ``cpu_argv`` instead, or skips it when that is None
    gpu: bool = False
    cpu_argv: tuple[str, ...] | None = None
    #: skipped in both modes, with this reason (e.g. a model that is not there)
    skip: str | None = None
    #: a module the step needs in the checked Python: skipped, with ``missing``, without it
    requires: str | None = None
    missing: str = ''
    #: runs even when the budget is spent (the summary)
    always: bool = False
    #: why a dry run skips it (a GPU step without ``cpu_argv``)
    dry_reason: str = 'needs a GPU and has no CPU counterpart'


@dataclass
class Outcome:
    name: str
    status: str  # ok, failed, timeout, skipped
    command: list[str] = field(default_factory=list)
    rc: int | None = None
    seconds: float = 0.0
    reason: str = ''
    log: str = ''


@dataclass(frozen=True)
class Config:
    dry_run: bool
    out: Path
    work: Path
    wheels: Path
    models: Path
    site: Path
    python: str
    frames: int
    size: str
    budget_s: float


def _rb(config: Config, *args: str) -> tuple[str, ...]:
    return (config.python, '-m', 'replaybench', *args)


def plan(config: Config) -> list[Step]:
    """The steps, in the order they run (the figures the issue asks for first)."""
    inputs = config.work / 'inputs'
    runs = config.work / 'runs'
    bag = str(inputs / 'rgb8_raw.mcap')
    jpeg = str(inputs / 'jpeg.mcap')
    stereo = str(inputs / 'stereo.mcap')
    rig = str(inputs / 'rig.mcap')
    seg = str(inputs / 'seg.mcap')
    seg_model = ('--model', str(REPO / 'replaybench' / 'models' / 'blobs_seg.onnx'))
    per_topic = ('--pipelines', 'per-topic')
    stereo_gpu = ('-b', 'onnx-stereo', '-b', 'cuda-stereo', '--engine', 'torch')
    yolox = config.models / 'yolox_nano.onnx'
    no_yolox = (
        None
        if yolox.is_file()
        else f'{yolox} not found: `make gpu-wheels` copies it from ../shared/real/models'
    )
    yolox_args = ('--model', str(yolox), '--labels', 'coco')
    common = ('--rate', 'max', '--no-report', '--force')

    def run(name: str, bag_path: str, *args: str) -> tuple[str, ...]:
        return _rb(config, 'run', bag_path, *args, *common, '--out', str(runs / name))

    def dnn(name: str, precision: str, model: tuple[str, ...], bag_path: str = bag) -> Step:
        gpu = run(
            name, bag_path, '-b', 'onnx-cpu', '-b', 'cuda', '--engine', 'torch',
            '--precision', precision, *model,
        )  # fmt: skip
        cpu = run(name, bag_path, '-b', 'onnx-cpu', *model) if precision == 'fp32' else None
        return Step(name, gpu, 120, gpu=True, cpu_argv=cpu, skip=no_yolox if model else None)

    wheels = sorted(str(path) for path in config.wheels.glob('*.whl'))
    install = (
        config.python, '-m', 'pip', 'install', '-q', '--no-index', '--no-deps', '--no-compile',
        '--no-cache-dir', '--upgrade', '--target', str(config.site),
    )  # fmt: skip
    peak_model = yolox_args if no_yolox is None else ()
    peak_gpu = _rb(config, 'peak', bag, '-b', 'cuda', '--engine', 'torch', '--precision', 'fp16')
    peak_gpu += (*peak_model, '--trial-frames', '120', '--min-hz', '60', '--max-hz', '4000')
    peak_gpu += (
        '--refine-steps',
        '3',
        '--no-report',
        '--force',
        '--out',
        str(config.work / 'peak'),
    )
    peak_cpu = _rb(config, 'peak', bag, '-b', 'null', '--trial-frames', str(config.frames))
    peak_cpu += ('--min-hz', '100', '--max-hz', '800', '--refine-steps', '1', '--no-report')
    peak_cpu += ('--force', '--out', str(config.work / 'peak'))
    sweep = _rb(config, 'sweep', bag, '-b', 'cuda', '--engine', 'torch', '--max-frames', '100')
    sweep += ('--no-report', '--out', str(config.work / 'sweep'))
    gpu_steps = (config.python, '-m', 'benchmarks.gpu_steps')
    fp16 = ('--precision', 'fp16')
    # run.json and summary.csv name onnx-cpu by its label, onnx_cpu
    against_cpu = ('--baseline-backend', 'onnx_cpu', '--allow-inconclusive')
    pytest = (config.python, '-m', 'pytest', '-rs', '-q', '-p', 'no:cacheprovider')
    return [
        Step('nvidia-smi', ('nvidia-smi',), 30, gpu=True),
        Step(
            'nvidia-smi-query',
            ('nvidia-smi', '--query-gpu=name,memory.total,driver_version', '--format=csv'),
            30,
            gpu=True,
        ),
        Step(
            'install-wheels',
            (*install, *wheels),
            120,
            gpu=True,
            dry_reason='uses this environment, not the wheels',
        ),
        Step('versions', (config.python, '-c', VERSIONS), 60),
        Step('doctor', _rb(config, 'doctor'), 90),
        Step('backends', _rb(config, 'backends'), 90),
        Step(
            'inputs',
            (
                *gpu_steps,
                'inputs',
                str(inputs),
                '--frames',
                str(config.frames),
                '--size',
                config.size,
            ),
            180,
        ),
        dnn('yolox-torch-fp16', 'fp16', yolox_args),
        dnn('yolox-torch-fp32', 'fp32', yolox_args),
        dnn('bundled-torch-fp32', 'fp32', ()),
        dnn('bundled-torch-fp16', 'fp16', ()),
        Step(
            'hsv',
            run('hsv', bag, '-b', 'hsv', '-b', 'hsv-cuda'),
            120,
            gpu=True,
            cpu_argv=run('hsv', bag, '-b', 'hsv', '-b', 'null'),
        ),
        Step(
            'stereo-cuda-torch',
            run('stereo-cuda-torch', stereo, *stereo_gpu),
            90,
            gpu=True,
            cpu_argv=run('stereo-cuda-torch', stereo, '-b', 'onnx-stereo'),
        ),
        Step(
            'seg-cuda-torch',
            run(
                'seg-cuda-torch',
                seg,
                '-b',
                'onnx-seg',
                '-b',
                'cuda',
                '--engine',
                'torch',
                *seg_model,
            ),
            90,
            gpu=True,
            cpu_argv=run('seg-cuda-torch', seg, '-b', 'onnx-seg', *seg_model),
        ),
        Step(
            'yolox-torch-fp16-jpeg',
            run(
                'yolox-torch-fp16-jpeg', jpeg, '-b', 'cuda', '--engine', 'torch', *fp16, *yolox_args
            ),
            120,
            gpu=True,
            skip=no_yolox,
        ),
        Step(
            'yolox-ort-fp32',
            run('yolox-ort-fp32', bag, '-b', 'cuda', '--engine', 'ort', *yolox_args),
            90,
            gpu=True,
            skip=no_yolox,
        ),
        Step(
            'compare-bundled',
            _rb(config, 'compare', str(runs / 'bundled-torch-fp32'), *against_cpu),
            60,
        ),
        Step(
            'compare-yolox',
            _rb(config, 'compare', str(runs / 'yolox-torch-fp32'), *against_cpu),
            60,
            skip=no_yolox,
        ),
        Step('peak-cuda', peak_gpu, 150, gpu=True, cpu_argv=peak_cpu),
        Step(
            'rig-cuda-shared',
            run('rig-cuda-shared', rig, '-b', 'cuda', '--engine', 'torch', *fp16),
            90,
            gpu=True,
            cpu_argv=run('rig-cuda-shared', rig, '-b', 'hsv'),
        ),
        Step(
            'rig-cuda-per-topic',
            run('rig-cuda-per-topic', rig, '-b', 'cuda', '--engine', 'torch', *fp16, *per_topic),
            90,
            gpu=True,
            cpu_argv=run('rig-cuda-per-topic', rig, '-b', 'hsv', *per_topic),
        ),
        Step(
            'pytest-gpu',
            (*pytest, 'tests/backends/gpu'),
            180,
            gpu=True,
            cpu_argv=(*pytest, '-p', 'no:xdist', 'tests/backends/gpu/test_gpu_on_device.py'),
        ),
        Step(
            'ray-sweep-cell',
            sweep,
            150,
            gpu=True,
            requires='ray',
            missing=RAY_MISSING,
            dry_reason='a Ray sweep cell with num_gpus=1 runs on the GPU machine only',
        ),
        Step(
            'summary',
            (*gpu_steps, 'summary', str(config.work), str(config.work / 'gpu-check')),
            60,
            always=True,
        ),
    ]


class Runner:
    """Runs the steps one after the other, each in its own process group with its own limit."""

    def __init__(self, config: Config, fail: set[str], hang: set[str]) -> None:
        self.config = config
        self.fail = fail
        self.hang = hang
        # the logs stay beside the runs: what comes back from a GPU machine is a few files
        # (the archive and copies of check.log, steps.json and summary.md in --out)
        self.folder = config.work / 'gpu-check'
        if self.folder.is_dir():
            shutil.rmtree(self.folder)
        self.logs = self.folder / 'logs'
        self.logs.mkdir(parents=True, exist_ok=True)
        self.main_log = (self.folder / 'check.log').open('a', encoding='utf-8')
        self.env = dict(os.environ)
        paths = [str(REPO)]
        if not config.dry_run:
            paths.append(str(config.site))
        if self.env.get('PYTHONPATH'):
            paths.append(self.env['PYTHONPATH'])
        self.env['PYTHONPATH'] = os.pathsep.join(paths)
        self.env['PYTHONUNBUFFERED'] = '1'
        self.started = time.monotonic()

    def say(self, text: str) -> None:
        print(text, flush=True)
        self.main_log.write(text + '\n')
        self.main_log.flush()

    def _has_module(self, module: str) -> bool:
        probe = (
            f'import importlib.util, sys; sys.exit(importlib.util.find_spec({module!r}) is None)'
        )
        done = subprocess.run(
            [self.config.python, '-c', probe], env=self.env, cwd=REPO, timeout=60, check=False
        )
        return done.returncode == 0

    def _command(self, step: Step) -> tuple[list[str], float, str]:
        """The command to run, its limit and why it is not the step's own ('' when it is)."""
        own = step.cpu_argv if self.config.dry_run and step.gpu else step.argv
        argv = list(own or step.argv)
        if step.name in self.hang:
            sleep = f'import time; time.sleep({HANG_TIMEOUT_S * 30})'
            return [self.config.python, '-c', sleep], HANG_TIMEOUT_S, '--hang'
        if step.name in self.fail:
            fail = 'import sys; print("failing on purpose (--fail)"); sys.exit(3)'
            return [self.config.python, '-c', fail], step.timeout_s, '--fail'
        return argv, step.timeout_s, ''

    def _skip_reason(self, step: Step) -> str:
        if step.skip:
            return step.skip
        if self.config.dry_run and step.gpu and step.cpu_argv is None:
            return f'dry run: {step.dry_reason}'
        if step.requires and not self.config.dry_run and not self._has_module(step.requires):
            return step.missing or f'{step.requires} is not installed'
        return ''

    def run(self, index: int, step: Step) -> Outcome:
        log = self.logs / f'{index:02d}-{step.name}.txt'
        elapsed = time.monotonic() - self.started
        left = self.config.budget_s - elapsed
        reason = self._skip_reason(step)
        if not reason and not step.always and left <= 0:
            reason = f'out of time: the budget of {self.config.budget_s:.0f} s is spent'
        if reason:
            self.say(f'== [{index:02d}] {step.name}: skipped ({reason})')
            return Outcome(step.name, 'skipped', reason=reason)
        argv, limit, why = self._command(step)
        if not step.always:
            limit = min(limit, max(left, 1.0))
        self.say(f'== [{index:02d}] {step.name} (limit {limit:.0f} s){" " + why if why else ""}')
        self.say('$ ' + ' '.join(argv))
        begin = time.monotonic()
        status, rc = 'ok', None
        with log.open('w', encoding='utf-8') as stream:
            stream.write('$ ' + ' '.join(argv) + '\n')
            stream.flush()
            try:
                process = subprocess.Popen(
                    argv,
                    stdout=stream,
                    stderr=subprocess.STDOUT,
                    stdin=subprocess.DEVNULL,
                    cwd=REPO,
                    env=self.env,
                    start_new_session=True,
                )
            except OSError as exc:
                stream.write(f'could not start: {exc}\n')
                status, rc = 'failed', 127
            else:
                try:
                    rc = process.wait(timeout=limit)
                except subprocess.TimeoutExpired:
                    os.killpg(process.pid, signal.SIGKILL)
                    process.wait()
                    status = 'timeout'
                    stream.write(f'\nkilled after its limit of {limit:.0f} s\n')
                else:
                    status = 'ok' if rc == 0 else 'failed'
        seconds = time.monotonic() - begin
        text = log.read_text(encoding='utf-8', errors='replace')
        for line in text.splitlines()[1:][-40:]:
            self.say('   ' + line)
        self.say(f'-- {step.name}: {status} (exit {rc}) in {seconds:.1f} s')
        return Outcome(step.name, status, argv, rc, round(seconds, 3), why, str(log.name))


def _pack(config: Config, folder: Path) -> Path:
    """check.log, steps.json, the summary, the step logs and the runs' JSON and CSV files."""
    archive = config.out / ARCHIVE
    extra = [
        path
        for root in (config.work / 'runs', config.work / 'peak', config.work / 'sweep')
        if root.is_dir()
        for path in sorted(root.rglob('*'))
        if path.is_file() and path.suffix in ('.json', '.csv')
    ]
    for keep_frames in (True, False):
        with tarfile.open(archive, 'w:gz') as tar:
            tar.add(folder, arcname='gpu-check')
            for path in extra:
                if keep_frames or path.name != 'frames.csv':
                    tar.add(path, arcname=f'gpu-check/{path.relative_to(config.work)}')
        if archive.stat().st_size <= ARCHIVE_LIMIT:
            break
    return archive


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='benchmarks/gpu_check.sh', description=__doc__)
    parser.add_argument('--dry-run', action='store_true', help='CPU mode: small inputs, no GPU')
    parser.add_argument('--out', type=Path, help='archive folder (default: $OUT)')
    parser.add_argument('--work', type=Path, help='inputs and run folders')
    parser.add_argument('--wheels', type=Path, default=REPO / '.whl')
    parser.add_argument('--models', type=Path, help='YOLOX-Nano folder (default: WHEELS/models)')
    parser.add_argument('--site', type=Path, default=Path('/tmp/replaybench-gpu-site'))
    parser.add_argument('--frames', type=int, help='frames per bag (300; dry run 30)')
    parser.add_argument('--size', help='WxH (1920x1080; dry run 160x120)')
    parser.add_argument('--budget', type=float, default=DEFAULT_BUDGET_S, help='seconds')
    parser.add_argument('--fail', action='append', default=[], metavar='STEP')
    parser.add_argument('--hang', action='append', default=[], metavar='STEP')
    args = parser.parse_args(argv)
    out = args.out or (Path(os.environ['OUT']) if os.environ.get('OUT') else None)
    if out is None:
        print('gpu_check: give --out DIR (or set OUT)', file=sys.stderr)
        return 2
    dry = bool(args.dry_run)
    config = Config(
        dry_run=dry,
        out=out.resolve(),
        work=(args.work or Path('/tmp/replaybench-gpu-check')).resolve(),
        wheels=args.wheels.resolve(),
        models=(args.models or args.wheels / 'models').resolve(),
        site=args.site.resolve(),
        python=sys.executable,
        frames=args.frames or (30 if dry else 300),
        size=args.size or ('160x120' if dry else '1920x1080'),
        budget_s=args.budget,
    )
    steps = plan(config)
    names = {step.name for step in steps}
    unknown = sorted((set(args.fail) | set(args.hang)) - names)
    if unknown:
        print(f'gpu_check: no step named {", ".join(unknown)}', file=sys.stderr)
        return 2
    config.out.mkdir(parents=True, exist_ok=True)
    runner = Runner(config, set(args.fail), set(args.hang))
    mode = 'dry run (CPU)' if dry else 'GPU'
    runner.say(f'gpu_check: {mode}, {len(steps)} steps, budget {config.budget_s:.0f} s')
    runner.say(f'work {config.work}, out {config.out}, python {config.python}')
    outcomes = []
    for index, step in enumerate(steps, start=1):
        if step.name == 'install-wheels' and not dry and not any(config.wheels.glob('*.whl')):
            reason = f'no wheels in {config.wheels}: run `make gpu-wheels` on the CPU machine first'
            runner.say(f'== [{index:02d}] {step.name}: failed ({reason})')
            outcomes.append(Outcome(step.name, 'failed', reason=reason))
            continue
        outcomes.append(runner.run(index, step))
    counts = {
        s: sum(o.status == s for o in outcomes) for s in ('ok', 'failed', 'timeout', 'skipped')
    }
    total = time.monotonic() - runner.started
    runner.say(f'gpu_check: {counts} in {total:.1f} s')
    record = {
        'mode': 'dry-run' if dry else 'gpu',
        'seconds': round(total, 3),
        'counts': counts,
        'steps': [vars(outcome) for outcome in outcomes],
    }
    (runner.folder / 'steps.json').write_text(json.dumps(record, indent=2) + '\n', encoding='utf-8')
    runner.main_log.close()
    archive = _pack(config, runner.folder)
    for name in RETURNED:
        if (runner.folder / name).is_file():
            shutil.copyfile(runner.folder / name, config.out / name)
    size = archive.stat().st_size
    print(f'gpu_check: {archive} {size} bytes', flush=True)
    if size > ARCHIVE_LIMIT:
        print(f'gpu_check: {archive} is over {ARCHIVE_LIMIT} bytes', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
