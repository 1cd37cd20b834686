"""`replaybench run` and `peak` outputs against a hostile world: bad --out folders, a full
disk, two runs on one folder, a killed run, a plugin backend that raises."""

from __future__ import annotations

import csv
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bagtools import image_msg, noise_frames, write_mcap

from replaybench.backends import ENTRY_POINT_GROUP
from replaybench.cli import app

pytestmark = pytest.mark.skipif(sys.platform == 'win32', reason='POSIX file system semantics')

REPO = Path(__file__).resolve().parents[1]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
NS = 1_000_000_000
runner = CliRunner()


def _bag(path: Path, n: int, size: tuple[int, int] = (64, 48)) -> Path:
    frames = noise_frames(12, width=size[0], height=size[1])
    t0 = 1_700_000_000 * NS
    write_mcap(
        path,
        [
            (
                '/cam/image_raw',
                t0 + i * NS // 30,
                image_msg(t0 + i * NS // 30, frames[i % 12]),
                'sensor_msgs/msg/Image',
            )
            for i in range(n)
        ],
    )
    return path


def _tree(folder: Path) -> dict[str, object]:
    """Every entry under ``folder`` as it is on disk: links, files' bytes and modes."""
    found: dict[str, object] = {}
    for path in sorted(folder.rglob('*')):
        key = str(path.relative_to(folder))
        if path.is_symlink():
            found[key] = ('link', os.readlink(path))
        elif path.is_dir():
            found[key] = ('dir', path.stat().st_mode)
        else:
            found[key] = ('file', path.stat().st_mode, path.read_bytes())
    return found


def _error_lines(stderr: str) -> list[str]:
    assert 'Traceback' not in stderr, stderr
    return [line for line in stderr.splitlines() if line.startswith('replaybench: error:')]


def _env(**extra: str) -> dict[str, str]:
    return {**os.environ, 'PYTHONWARNINGS': 'ignore', **extra}


def _spawn(*args: str, **kwargs: Any) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, '-m', 'replaybench', *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_env(),
        **kwargs,
    )


def _wait_for_replay(process: subprocess.Popen[str], parent: Path, name: str = 'run') -> None:
    """Until the run writes its rows (into the temporary folder beside OUT)."""
    deadline = time.monotonic() + 60
    while not list(parent.glob(f'.{name}.tmp-*/frames.csv.part')):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, 'the run did not start'
        time.sleep(0.05)


def _consistent(out: Path) -> dict[str, Any]:
    """run.json, frames.csv and summary.csv count the same frames; run.json returned."""
    run: dict[str, Any] = json.loads((out / 'run.json').read_text())
    with (out / 'frames.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    with (out / 'summary.csv').open(newline='') as f:
        summary = list(csv.DictReader(f))
    assert len(rows) == run['counts']['frames'] == sum(int(s['frames']) for s in summary)
    assert sum(r['status'] == 'ok' for r in rows) == run['counts']['processed']
    return run


# -- a bad --out: exit 2, one line, nothing created, nothing touched ---------------------------


def _under_a_file(tmp_path: Path) -> Path:
    (tmp_path / 'notes.txt').write_text('mine')
    return tmp_path / 'notes.txt' / 'run'


def _dangling_link(tmp_path: Path) -> Path:
    (tmp_path / 'run').symlink_to(tmp_path / 'gone')
    return tmp_path / 'run'


def _foreign_folder(tmp_path: Path) -> Path:
    (tmp_path / 'photos').mkdir()
    (tmp_path / 'photos' / 'holiday.jpg').write_bytes(b'\xff\xd8mine')
    return tmp_path / 'photos'


def _read_only_folder(tmp_path: Path) -> Path:
    if os.geteuid() == 0:
        pytest.skip('root writes into a read-only folder: the refusal cannot be seen as root')
    (tmp_path / 'ro').mkdir()
    (tmp_path / 'ro').chmod(0o555)
    return tmp_path / 'ro' / 'run'


BAD_OUTS = {
    'under a regular file': (_under_a_file, [], 'not a directory'),
    'a dangling symbolic link': (_dangling_link, [], 'dangling symbolic link'),
    'a non-empty folder without --force': (_foreign_folder, [], 'not empty'),
    'a folder that is no run folder with --force': (_foreign_folder, ['--force'], 'no {marker}'),
    'inside a read-only folder': (_read_only_folder, [], 'not writable'),
}
COMMANDS = {
    'run': (['run', str(RAW), '--backend', 'null'], 'run.json'),
    'peak': (['peak', str(RAW), '--backend', 'null', '--trial-frames', '4'], 'peak.json'),
}


@pytest.mark.parametrize('command', list(COMMANDS))
@pytest.mark.parametrize('case', list(BAD_OUTS))
def test_a_bad_out_exits_2_with_one_line_and_creates_or_touches_nothing(
    tmp_path: Path, case: str, command: str
) -> None:
    make, extra, expected = BAD_OUTS[case]
    args, marker = COMMANDS[command]
    out = make(tmp_path)
    before = _tree(tmp_path)
    result = runner.invoke(app, [*args, '--out', str(out), *extra])
    assert result.exit_code == 2, (result.output, result.exception)
    (line,) = _error_lines(result.stderr)
    assert expected.format(marker=marker) in line
    assert _tree(tmp_path) == before


NOBODY = ['--reuid=65534', '--regid=65534', '--clear-groups']


@pytest.mark.skipif(os.geteuid() != 0, reason='as another user, the in-process case covers it')
@pytest.mark.skipif(shutil.which('setpriv') is None, reason='setpriv (util-linux) not installed')
@pytest.mark.parametrize('command', list(COMMANDS))
def test_a_read_only_folder_is_refused_for_a_user_who_cannot_write_there(command: str) -> None:
    args, _ = COMMANDS[command]
    base = Path(tempfile.mkdtemp(prefix='rb-read-only-'))  # reachable by that user, not tmp_path
    try:
        base.chmod(0o755)
        (base / 'ro').mkdir(mode=0o555)
        before = _tree(base)
        argv = [*args, '--out', str(base / 'ro' / 'run')]
        result = subprocess.run(
            ['setpriv', *NOBODY, sys.executable, '-m', 'replaybench', *argv],
            capture_output=True,
            text=True,
            env=_env(),
            cwd=base,
            timeout=120,
            check=False,
        )
        assert result.returncode == 2, result.stderr
        (line,) = _error_lines(result.stderr)
        assert 'not writable' in line
        assert _tree(base) == before
    finally:
        shutil.rmtree(base)


def test_a_run_that_measures_no_frame_exits_2_with_one_line_and_leaves_nothing(tmp_path):
    out = tmp_path / 'run'
    result = runner.invoke(
        app, ['run', str(RAW), '--backend', 'null', '--duration', '0', '--out', str(out)]
    )
    assert result.exit_code == 2
    (line,) = _error_lines(result.stderr)
    assert 'no frame was measured' in line
    assert '--duration 0 s' in line
    assert list(tmp_path.iterdir()) == []


# -- a full disk: exit 1, one line naming the file, nothing left, the previous run intact ------


def _file_size_limit(limit: int) -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG


@pytest.mark.parametrize('previous', [True, False], ids=['over a previous run', 'a new folder'])
def test_a_write_that_fails_exits_1_naming_the_file_and_leaves_nothing_behind(
    tmp_path: Path, previous: bool
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', n=900, size=(16, 12))
    out = tmp_path / 'run'
    if previous:
        first = runner.invoke(app, ['run', str(bag), '--backend', 'null', '--out', str(out)])
        assert first.exit_code == 0, first.output
    before = _tree(tmp_path)
    # frames.csv reaches 64 KiB at about 500 rows; the other files stay below
    process = _spawn(
        'run',
        str(bag),
        '--backend',
        'null',
        '--out',
        str(out),
        '--force',
        preexec_fn=lambda: _file_size_limit(64 << 10),
    )
    _, stderr = process.communicate(timeout=240)
    assert process.returncode == 1, stderr
    (line,) = _error_lines(stderr)
    assert line == f'replaybench: error: cannot write {out / "frames.csv"}: File too large'
    assert _tree(tmp_path) == before


# -- two runs on one folder: the second is refused at once -------------------------------------


def test_a_second_run_on_the_same_out_is_refused_at_once_and_the_first_finishes_whole(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', n=300)  # 10 s at the recorded rate
    out = tmp_path / 'run'
    first = _spawn('run', str(bag), '--backend', 'null', '--rate', 'recorded', '--out', str(out))
    try:
        _wait_for_replay(first, tmp_path)
        began = time.monotonic()
        command = ['run', str(bag), '--backend', 'hsv', '--max-frames', '3']
        second = subprocess.run(
            [sys.executable, '-m', 'replaybench', *command, '--out', str(out), '--force'],
            capture_output=True,
            text=True,
            env=_env(),
            timeout=120,
            check=False,
        )
        assert second.returncode == 2, second.stderr
        (line,) = _error_lines(second.stderr)
        assert 'in use by another replaybench run' in line
        assert f'(pid {first.pid})' in line
        assert first.poll() is None, 'the second run was refused only after the first ended'
        assert time.monotonic() - began < 30
    finally:
        first.send_signal(signal.SIGINT)
        _, stderr = first.communicate(timeout=60)
    assert first.returncode == 130, stderr
    run = _consistent(out)
    assert run['status'] == 'interrupted'
    assert {b['name'] for b in run['backends']} == {'null'}
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'run']


# -- SIGKILL: the previous run is intact, and the next run cleans up --------------------------


def _kill_mid_run(tmp_path: Path, bag: Path, *args: str) -> None:
    process = _spawn('run', str(bag), '--backend', 'null', '--rate', 'recorded', *args)
    _wait_for_replay(process, tmp_path)
    process.kill()
    process.communicate(timeout=30)
    assert process.returncode == -signal.SIGKILL


def test_a_killed_forced_run_leaves_the_previous_run_byte_for_byte_and_the_next_run_works(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', n=300)
    out = tmp_path / 'run'
    first = runner.invoke(
        app, ['run', str(bag), '--backend', 'null', '--max-frames', '5', '--out', str(out)]
    )
    assert first.exit_code == 0, first.output
    before = _tree(out)
    _kill_mid_run(tmp_path, bag, '--out', str(out), '--force')
    assert _tree(out) == before
    assert [p.name for p in tmp_path.glob('.run.tmp-*')], 'the killed run left no temporary folder'
    again = runner.invoke(
        app,
        ['run', str(bag), '--backend', 'null', '--max-frames', '7', '--out', str(out), '--force'],
    )
    assert again.exit_code == 0, again.output
    assert _consistent(out)['counts']['frames'] == 7
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'run']


def test_a_killed_run_leaves_no_folder_so_the_same_command_works_without_force(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=300)
    out = tmp_path / 'run'
    _kill_mid_run(tmp_path, bag, '--out', str(out))
    assert not out.exists()
    again = runner.invoke(
        app, ['run', str(bag), '--backend', 'null', '--max-frames', '4', '--out', str(out)]
    )
    assert again.exit_code == 0, again.output
    assert _consistent(out)['status'] == 'complete'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'run']


# -- a plugin backend that raises --------------------------------------------------------------


def _install_plugin(folder: Path) -> Path:
    """A distribution on a path entry registering two backends through the entry point group:
    `boom` raises in detect() from seq 5 on, `brokenopen` raises in open()."""
    folder.mkdir()
    (folder / 'rb_boom.py').write_text(
        textwrap.dedent(
            """
            from replaybench.backends.null import NullBackend

            class Boom(NullBackend):
                name = 'boom'

                def detect(self, frame):
                    if frame.seq >= 5:
                        raise RuntimeError(f'boom at {frame.seq}')
                    return super().detect(frame)

            class BrokenOpen(NullBackend):
                name = 'brokenopen'

                def open(self):
                    raise OSError('no such device: /dev/npu0')
            """
        )
    )
    dist = folder / 'rb_boom-0.1.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text('Metadata-Version: 2.1\nName: rb-boom\nVersion: 0.1\n')
    (dist / 'entry_points.txt').write_text(
        f'[{ENTRY_POINT_GROUP}]\nboom = rb_boom:Boom\nbrokenopen = rb_boom:BrokenOpen\n'
    )
    return folder


def _run_with_plugin(
    plugin: Path, *args: str, debug: bool = False
) -> subprocess.CompletedProcess[str]:
    flags = ['--debug'] if debug else []
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', *flags, 'run', str(RAW), *args],
        capture_output=True,
        text=True,
        env=_env(PYTHONPATH=str(plugin)),
        timeout=240,
        check=False,
    )


def test_a_plugin_backend_that_raises_is_recorded_the_others_finish_and_the_run_exits_1(
    tmp_path: Path,
) -> None:
    plugin = _install_plugin(tmp_path / 'plugin')
    out = tmp_path / 'run'
    result = _run_with_plugin(plugin, '--backend', 'boom', '--backend', 'null', '--out', str(out))
    assert result.returncode == 1, result.stderr
    (line,) = _error_lines(result.stderr)
    assert "backend 'boom' raised on input 0 /camera/image_raw seq 5: RuntimeError: boom at 5" in (
        line
    )
    run = _consistent(out)
    assert run['status'] == 'partial'
    boom, null = run['backends']
    assert (boom['status'], boom['error']['seq']) == ('failed', 5)
    assert (null['status'], null['error']) == ('ok', None)
    with (out / 'frames.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
    assert sum(r['backend'] == 'boom' for r in rows) == 5
    assert sum(r['backend'] == 'null' for r in rows) == 10
    assert (out / 'report.html').is_file()


def test_a_plugin_backend_that_cannot_open_exits_2_with_one_line_before_anything_is_written(
    tmp_path: Path,
) -> None:
    plugin = _install_plugin(tmp_path / 'plugin')
    out = tmp_path / 'run'
    result = _run_with_plugin(
        plugin, '--backend', 'null', '--backend', 'brokenopen', '--out', str(out)
    )
    assert result.returncode == 2, result.stderr
    (line,) = _error_lines(result.stderr)
    assert "backend 'brokenopen' could not be opened: OSError: no such device" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ['plugin']


def test_with_debug_a_plugin_that_cannot_open_shows_its_own_traceback_then_the_one_line(
    tmp_path: Path,
) -> None:
    plugin = _install_plugin(tmp_path / 'plugin')
    out = tmp_path / 'run'
    result = _run_with_plugin(plugin, '--backend', 'brokenopen', '--out', str(out), debug=True)
    assert result.returncode == 2, result.stderr
    assert 'The above exception was the direct cause of the following exception' in result.stderr
    assert 'rb_boom.py' in result.stderr  # the plugin's frame, where open() raised
    assert 'OSError: no such device: /dev/npu0' in result.stderr
    last = result.stderr.splitlines()[-1]
    assert last.startswith('replaybench: error: ')
    assert "backend 'brokenopen' could not be opened" in last
    assert not out.exists()
