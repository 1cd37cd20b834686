"""The command line's habits: help that reads as instructions, usage errors in two lines, runs
that fail after parsing leave nothing behind, compare prints without --out, and
``replaybench fixtures`` shows its progress."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from replaybench.cli import app
from replaybench.cli.progress import FixtureProgress

REPO = Path(__file__).resolve().parents[1]
RAW = str(REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap')
COMMANDS = sorted(typer.main.get_command(app).commands)  # type: ignore[attr-defined]
runner = CliRunner()


def _files(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob('*')}


# -- help --------------------------------------------------------------------------------------


def test_the_app_has_the_commands_the_docs_describe() -> None:
    assert set(COMMANDS) >= {'run', 'info', 'backends', 'doctor', 'fixtures', 'peak', 'sweep'}
    assert set(COMMANDS) >= {'compare', 'report'}


@pytest.mark.parametrize('command', [None, *COMMANDS])
def test_every_help_opens_with_an_imperative_sentence_and_shows_an_example(command) -> None:
    args = [command, '--help'] if command else ['--help']
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    paragraphs = [p for p in re.split(r'\n\s*\n', result.stdout) if p.strip()]
    assert paragraphs[0].startswith('Usage: replaybench')
    opening = ' '.join(paragraphs[1].split())
    first_sentence = opening.split('. ')[0]
    first_word = first_sentence.split()[0]
    # an instruction: "Replay ...", "List ...", not "Replays ..." or "This command ..."
    assert first_word[0].isupper(), opening
    assert not first_word.endswith('s') or first_word.endswith('ss'), opening
    assert first_word not in {'The', 'A', 'An', 'This', 'It'}, opening
    assert opening.endswith('.'), opening
    # an example, on one line, to copy into a shell
    examples = [ln.strip() for ln in result.stdout.splitlines() if 'Example:' in ln]
    assert examples, result.stdout
    expected = f'Example: replaybench {command}' if command else 'Example: replaybench '
    assert examples[0].startswith(expected), examples


@pytest.mark.parametrize('command', COMMANDS)
def test_help_shows_placeholders_people_read(command) -> None:
    text = runner.invoke(app, [command, '--help']).stdout
    assert '<list' not in text
    assert '{' not in text.split('Arguments:')[0]
    assert not re.search(r'\b(INTEGER|FLOAT|TEXT)\b', text), text


def test_run_help_names_its_arguments_bag_dir_name_n_and_path() -> None:
    text = runner.invoke(app, ['run', '--help']).stdout
    assert 'Usage: replaybench run [OPTIONS] BAG...' in text
    for shown in ('--backend NAME', '--out DIR', '--max-frames N', '--config PATH'):
        assert shown in text, shown
    assert '--no-hash' in text


# -- usage errors ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ('args', 'named'),
    [
        (['run', RAW, '-b', 'hsv', '--queue-depth', 'zero'], 'zero'),
        (['run', RAW, '-b', 'hsv', '--rate', 'fast'], 'fast'),
        (['run', RAW, '-b', 'hsv', '--precision', 'fp8'], 'fp8'),
        (['run', RAW, '-b', 'hsv', '--engine', 'warp'], 'warp'),
        (['run', RAW, '-b', 'hsv', '--frobnicate'], '--frobnicate'),
        (['run', RAW, '-b', 'yolo9000'], 'yolo9000'),
        (['peak', RAW, '-b', 'hsv', '--max-drop', '2'], '2'),
        (['peak', RAW, '-b', 'yolo9000'], 'yolo9000'),
        (['fixtures', '--out', 'x', '--size', '12x'], '12x'),
        (['compare', RAW, '--fail-if', 'p99 >> 3'], 'p99 >> 3'),
        (['info', RAW, '--verbose'], '--verbose'),
        (['report', '--zzz', 'x'], '--zzz'),
    ],
    ids=lambda value: '_'.join(value) if isinstance(value, list) else value,
)
def test_a_bad_value_unknown_option_or_unknown_backend_exits_2_in_two_lines_naming_it(
    tmp_path, monkeypatch, args, named
) -> None:
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert 1 <= len(lines) <= 2, result.stderr
    assert named in lines[0], result.stderr
    assert 'Traceback' not in result.output
    assert result.stdout == ''
    assert _files(tmp_path) == set()  # nothing written, not even a run folder


# -- a run that fails after parsing ------------------------------------------------------------


def test_an_invalid_config_leaves_no_out_folder_and_the_same_command_works_once_fixed(
    tmp_path,
) -> None:
    config = tmp_path / 'hsv.toml'
    config.write_text('min_area = [50\n', encoding='utf-8')
    out = tmp_path / 'run'
    args = ['run', RAW, '-b', 'hsv', '--config', str(config), '--out', str(out), '--no-report']
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert 'hsv.toml' in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert _files(tmp_path) == {'hsv.toml'}
    config.write_text((REPO / 'docs' / 'hsv-default.toml').read_text(encoding='utf-8'))
    result = runner.invoke(app, args)  # the same command line, no --force
    assert result.exit_code == 0, result.output
    assert (out / 'run.json').is_file()


def test_a_missing_labels_file_leaves_no_out_folder_and_the_same_command_works_once_fixed(
    tmp_path, monkeypatch
) -> None:
    monkeypatch.chdir(tmp_path)
    args = ['run', RAW, '-b', 'onnx-cpu', '--labels', 'names.txt', '--max-frames', '2']
    args += ['--out', 'run', '--no-report']
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert 'names.txt' in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert _files(tmp_path) == set()
    Path('names.txt').write_text('red\ngreen\nblue\nyellow\n', encoding='utf-8')
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert Path('run', 'run.json').is_file()


def test_an_unknown_topic_leaves_no_out_folder(tmp_path) -> None:
    out = tmp_path / 'run'
    result = runner.invoke(app, ['run', RAW, '-b', 'hsv', '--topic', '/nope', '--out', str(out)])
    assert result.exit_code == 2
    assert '/nope' in result.stderr
    assert '/camera/image_raw' in result.stderr  # the topics there are
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert _files(tmp_path) == set()


# -- compare without --out ---------------------------------------------------------------------


@pytest.fixture(scope='module')
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two runs of hsv and null over the same fixture bag (10 frames, 9 measured)."""
    base = tmp_path_factory.mktemp('runs')
    runs = (base / 'main', base / 'branch')
    for out in runs:
        args = ['run', RAW, '-b', 'hsv', '-b', 'null', '--out', str(out), '--no-report']
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
    return runs


@pytest.fixture(scope='module')
def short_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two runs of hsv over 3 frames each: too few for any interval, so a timing condition is
    inconclusive whatever the timings."""
    base = tmp_path_factory.mktemp('short')
    runs = (base / 'main', base / 'branch')
    for out in runs:
        args = ['run', RAW, '-b', 'hsv', '--max-frames', '3', '--out', str(out), '--no-report']
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
    return runs


@pytest.mark.parametrize(
    ('runs', 'conditions', 'verdict', 'code'),
    [
        ('two_runs', [], None, 0),
        # the same backend over the same frames: the same detections
        ('two_runs', ['map50 < -0.02'], 'passed', 0),
        # 3 frames a run cannot decide a p99 either way
        ('short_runs', ['p99_ms > +10%'], 'INCONCLUSIVE', 3),
    ],
)
def test_compare_without_out_prints_the_table_writes_nothing_and_exits_with_the_verdict(
    request, tmp_path, monkeypatch, runs, conditions, verdict, code
) -> None:
    two_runs = request.getfixturevalue(runs)
    monkeypatch.chdir(tmp_path)
    before = {run: _files(run) for run in two_runs}
    args = ['compare', *map(str, two_runs)]
    for condition in conditions:
        args += ['--fail-if', condition]
    result = runner.invoke(app, args)
    assert result.exit_code == code, result.output
    assert 'baseline: main' in result.stdout
    assert re.search(r'^\s+branch .*hsv .*: median ×\d', result.stdout, re.MULTILINE), result.stdout
    if verdict is not None:
        assert f'gate: {verdict}' in result.stdout
    assert 'Comparison:' not in result.stdout
    assert _files(tmp_path) == set()
    assert {run: _files(run) for run in two_runs} == before


def test_compare_exits_1_when_a_condition_fails_without_out(two_runs, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    # one run: its null backend compared with its hsv backend loses all of hsv's accuracy
    result = runner.invoke(app, ['compare', str(two_runs[0]), '--fail-if', 'map50 < -0.5'])
    assert result.exit_code == 1, result.output
    assert 'gate: FAILED' in result.stdout
    assert _files(tmp_path) == set()


def test_compare_with_out_names_every_file_it_writes(two_runs, tmp_path) -> None:
    out = tmp_path / 'cmp'
    result = runner.invoke(app, ['compare', *map(str, two_runs), '--out', str(out)])
    assert result.exit_code == 0, result.output
    written = _files(out)
    assert written == {'comparison.html', 'comparison.csv', 'comparison.json'}
    for name in written:
        assert str(out / name) in result.stdout, name
    assert json.loads((out / 'comparison.json').read_text(encoding='utf-8'))['gate'] is None


# -- fixtures progress -------------------------------------------------------------------------


class _Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_fixture_progress_off_a_terminal_is_a_line_every_ten_seconds_and_none_when_quick():
    clock, stream = _Clock(), io.StringIO()
    progress = FixtureProgress(stream, clock=clock)
    for done in range(1, 301):
        clock.now = done * 0.1  # 30 s for the bag's 300 frames
        progress('rgb8_raw.mcap', done, 300)
    lines = stream.getvalue().splitlines()
    assert lines == [
        'replaybench: writing rgb8_raw.mcap: 100/300 frames (10 s)',
        'replaybench: writing rgb8_raw.mcap: 200/300 frames (20 s)',
        'replaybench: writing rgb8_raw.mcap: 300/300 frames (30 s)',
    ]
    quick, stream = _Clock(), io.StringIO()
    progress = FixtureProgress(stream, clock=quick)
    for done in range(1, 11):
        quick.now = done * 0.01
        progress('jpeg.mcap', done, 10)
    assert stream.getvalue() == ''


def test_fixture_progress_on_a_terminal_redraws_one_line_per_bag():
    clock, stream = _Clock(), _Terminal()
    progress = FixtureProgress(stream, clock=clock)
    for name in ('rgb8_raw.mcap', 'jpeg.mcap'):
        for done in range(1, 4):
            clock.now += 1.0
            progress(name, done, 3)
    text = stream.getvalue()
    assert text.count('\n') == 2
    assert '\rreplaybench: writing rgb8_raw.mcap: 3/3 frames\n' in text
    assert '\rreplaybench: writing jpeg.mcap: 2/3 frames' in text


def test_the_fixtures_command_reports_progress_per_bag_and_frame(tmp_path, monkeypatch) -> None:
    import replaybench.fixtures as fixtures_package

    calls: list[tuple[str, int, int]] = []
    real = fixtures_package.generate_fixtures

    def recording(*args: object, progress: object = None, **kwargs: object) -> list[Path]:
        assert isinstance(progress, FixtureProgress)

        def both(name: str, done: int, total: int) -> None:
            calls.append((name, done, total))
            progress(name, done, total)

        return real(*args, progress=both, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(fixtures_package, 'generate_fixtures', recording)
    result = runner.invoke(app, ['fixtures', '--out', str(tmp_path / 'bags'), '--frames', '2'])
    assert result.exit_code == 0, result.output
    assert result.stderr == ''  # quick, and not a terminal: no progress line
    names = [
        'rgb8_raw.mcap',
        'jpeg.mcap',
        'bgr8_rosbag2',
        'rgb8.bag',
        'two_camera.mcap',
        'live_detections.mcap',
        'live_tracks.mcap',
    ]
    assert calls == [(name, done, 2) for name in names for done in (1, 2)]


# -- --no-hash ---------------------------------------------------------------------------------


def test_no_hash_records_a_null_sha256_and_says_so_on_the_terminal(two_runs, tmp_path) -> None:
    out = tmp_path / 'run'
    args = ['run', RAW, '-b', 'hsv', '-b', 'null', '--out', str(out), '--no-report', '--no-hash']
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert 'sha256' in result.stderr
    assert '--no-hash' in result.stderr
    run = json.loads((out / 'run.json').read_text(encoding='utf-8'))
    assert run['inputs'][0]['sha256'] is None
    # and compare, against a run that has the sha256, says the inputs were not checked
    cmp = tmp_path / 'cmp'
    compared = runner.invoke(app, ['compare', str(two_runs[0]), str(out), '--out', str(cmp)])
    assert compared.exit_code == 0, compared.output
    rows = (cmp / 'comparison.csv').read_text(encoding='utf-8')
    assert 'not checked' in rows


def test_help_lists_the_commands_in_the_order_of_the_command_modules() -> None:
    from replaybench.cli import COMMAND_MODULES

    result = CliRunner().invoke(app, ['--help'])
    assert result.exit_code == 0
    listed = [
        line.split()[0]
        for line in result.output.split('Commands:', 1)[1].splitlines()
        if line.startswith('  ') and line.strip()
    ]
    assert listed == [
        'run',
        'info',
        'backends',
        'doctor',
        'fixtures',
        'peak',
        'sweep',
        'compare',
        'report',
        'quantize',
    ]
    package = Path(__file__).resolve().parents[1] / 'replaybench' / 'cli'
    modules = {p.stem for p in package.glob('*.py')} - {
        '__init__',
        '_common',
        '_values',
        'progress',
    }
    assert modules == set(COMMAND_MODULES)
