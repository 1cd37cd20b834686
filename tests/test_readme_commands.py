"""Every ``replaybench ...`` command in README.md and docs/*.md runs as written.

A newcomer copies the commands of the README (after ``make run`` and ``. .venv/bin/activate``)
into a fresh shell at the repository root. This test does the same: it extracts each command
from the code blocks (indented or fenced; a trailing ``\\`` continues it on the next line) and
runs it with bash in a copy of the repository root (``fixtures/``, ``docs/``, and ``shared/``
beside it), the commands of one file one after another in their order, the files in parallel,
with pandas made unimportable: the command line must work on the default install, which leaves
pandas (the Python API's ``pandas`` extra) out.

A command is expected to exit 0, unless it says otherwise in a trailing comment
(``replaybench compare ... # exits 3: ...``, or ``# exits 0, 1 or 3: ...`` where the document
says the outcome is not decided by the command, such as a timing gate over a few noisy
frames); ``replaybench doctor`` is expected to exit as
docs/cli.md says, 0 where every GPU backend is available and 1 elsewhere. A command is not run
when it cannot run here:

* it holds a placeholder: a word in capitals (``BAG``, ``DIR``, ``N``; the synopsis lines), a
  ``$VARIABLE``, or a name that the document declares a placeholder in its own code block, with
  a comment line ``# placeholders: drive.mcap, labels.json (your files)``;
* it names a GPU backend (``cuda``, ``tensorrt``, ``hsv-cuda``) that is not available here, or
  stands in a code block with the comment line ``# needs: an NVIDIA GPU`` where no GPU backend
  is available (a GPU is the only need a block may declare);
* it needs a cluster (``--address``), Ray for ``sweep`` where the ``sweep`` extra is not
  installed, or the real recordings of ``../shared`` where there are none.

The README's examples are all run: only its synopsis lines (placeholders in capitals) are not.

Skipped commands are listed in the test's output, each with its reason. Commands that replay a
whole bag get ``--max-frames`` only where the document already says so: they run on the bundled
fixtures of 10 frames.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
import tomllib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / 'README.md', *sorted((REPO / 'docs').glob('*.md'))]
GPU_BACKENDS = ('cuda', 'tensorrt', 'hsv-cuda', 'cuda-stereo', 'tensorrt-stereo')
COMMAND_TIMEOUT_S = 300
_PLACEHOLDER_WORD = re.compile(r'(?<![\w.-])(?:[A-Z][A-Z0-9_]*)(?![\w-])')
_VARIABLE = re.compile(r'\$\{?[A-Za-z_]')
_EXIT = re.compile(r'#.*\bexits? (?:with )?(?:status )?(\d+(?:(?:,| or|, or) \d+)*)\b')
_PLACEHOLDERS = re.compile(r'^#\s*placeholders?:\s*(.*)$', re.IGNORECASE)
_NEEDS = re.compile(r'^#\s*needs:\s*(.*)$', re.IGNORECASE)
SHARED = REPO.parent / 'shared'


@dataclass(frozen=True)
class Command:
    doc: str
    line: int
    text: str  # as written, continuation lines joined
    expected: tuple[int, ...]  # the exit statuses the document gives it
    skip: str | None  # why it is not run here


def _code_blocks(text: str) -> list[tuple[int, list[str]]]:
    """(first line number, lines) of each fenced or indented code block of a Markdown text."""
    blocks: list[tuple[int, list[str]]] = []
    lines = text.splitlines()
    i = 0
    previous_blank = True
    while i < len(lines):
        line = lines[i]
        fence = re.match(r'^\s*(```|~~~)', line)
        if fence:
            start, body = i + 2, []
            i += 1
            while i < len(lines) and not lines[i].lstrip().startswith(fence.group(1)):
                body.append(lines[i])
                i += 1
            blocks.append((start, body))
            i += 1
            previous_blank = True
            continue
        if line.startswith('    ') and previous_blank and line.strip():
            start, body = i + 1, []
            while i < len(lines) and (lines[i].startswith('    ') or not lines[i].strip()):
                body.append(lines[i][4:])
                i += 1
            blocks.append((start, body))
            previous_blank = False
            continue
        previous_blank = not line.strip()
        i += 1
    return blocks


def _commands_of(path: Path, doc: str | None = None) -> list[Command]:
    doc = doc or path.relative_to(REPO).as_posix()
    blocks = _code_blocks(path.read_text(encoding='utf-8'))
    declared: set[str] = set()
    for _, body in blocks:
        for line in body:
            found = _PLACEHOLDERS.match(line.strip())
            if found:
                names = re.sub(r'\(.*?\)', '', found.group(1))
                declared |= {w for w in re.split(r'[\s,]+', names) if w}
    commands = []
    for start, body in blocks:
        needs = [m.group(1) for m in (_NEEDS.match(line.strip()) for line in body) if m]
        for need in needs:
            if 'GPU' not in need:
                msg = f'{doc}:{start}: unknown need {need!r} (only a GPU can be declared)'
                raise ValueError(msg)
        i = 0
        while i < len(body):
            line = body[i].strip()
            first = i
            i += 1
            if line.startswith('$ '):
                line = line[2:]
            if not re.match(r'^(\.venv/bin/)?replaybench(\s|$)', line):
                continue
            while line.endswith('\\') and i < len(body):
                line = line[:-1].rstrip() + ' ' + body[i].strip()
                i += 1
            commands.append(_command(doc, start + first, line, declared, gpu_block=bool(needs)))
    return commands


def _command(
    doc: str, line: int, text: str, declared: set[str], *, gpu_block: bool = False
) -> Command:
    code, _, comment = text.partition(' #')
    found = _EXIT.search('#' + comment) if comment else None
    expected = tuple(int(n) for n in re.findall(r'\d+', found.group(1))) if found else (0,)
    words = shlex.split(code)
    if words[1:2] == ['doctor'] and '|' not in words and not found:
        expected = (0,) if all(_gpu_available(name) for name in GPU_BACKENDS) else (1,)
    skip = None
    options = [(a, b) for a, b in zip(words, [*words[1:], ''], strict=True)]
    unquoted = re.sub(r'(["\']).*?\1', '', code)
    if _VARIABLE.search(code):
        skip = 'placeholder: a shell variable'
    elif any(w in declared for w in words) or any(
        p in w for p in declared if '/' in p or '.' in p for w in words
    ):
        skip = 'placeholder declared in the document'
    elif _PLACEHOLDER_WORD.search(unquoted):
        skip = f'placeholder: {_PLACEHOLDER_WORD.search(unquoted).group(0)}'  # type: ignore[union-attr]
    elif any(opt == '--address' for opt, _ in options):
        skip = 'needs a Ray cluster (--address)'
    elif gpu_block and not any(_gpu_available(name) for name in GPU_BACKENDS):
        skip = 'its code block needs an NVIDIA GPU, and no GPU backend is available here'
    elif words[1:2] == ['sweep'] and not _sweep_installed():
        skip = 'needs the sweep extra (Ray), not installed here'
    elif '../shared/' in code and not SHARED.is_dir():
        skip = 'needs the real recordings of ../shared, absent here'
    else:
        gpu = [b for opt, b in options if opt in ('--backend', '-b') and b in GPU_BACKENDS]
        if gpu and not _gpu_available(gpu[0]):
            skip = f'GPU backend {gpu[0]} is not available here'
    return Command(doc, line, text, expected, skip)


@functools.cache
def _gpu_available(name: str) -> bool:
    from replaybench.backends import backend_table

    return any(row.name == name and row.availability.ok for row in backend_table())


def _sweep_installed() -> bool:
    return importlib.util.find_spec('ray') is not None


ALL = [c for path in DOCS for c in _commands_of(path)]


def _workspace(root: Path) -> Path:
    """A copy of what the commands read: the repository root's fixtures/ and docs/, shared/
    beside it (read-only real recordings, linked), and pyproject.toml."""
    repo = root / 'repo'
    repo.mkdir(parents=True)
    shutil.copytree(REPO / 'fixtures', repo / 'fixtures')
    shutil.copytree(REPO / 'docs', repo / 'docs')
    shutil.copy2(REPO / 'pyproject.toml', repo / 'pyproject.toml')
    shared = REPO.parent / 'shared'
    if shared.is_dir():
        (root / 'shared').symlink_to(shared)
    # the default install has no pandas (the `pandas` extra): a package in its place that
    # cannot be imported, first on PYTHONPATH
    blocker = root / 'no-pandas' / 'pandas'
    blocker.mkdir(parents=True)
    (blocker / '__init__.py').write_text(
        "raise ImportError('No module named pandas (not in the default install)')\n",
        encoding='utf-8',
    )
    return repo


def _environment(cwd: Path) -> dict[str, str]:
    """A person's shell with the default install: the venv's bin first on PATH, no pandas."""
    env = dict(os.environ)
    env['PATH'] = f'{Path(sys.executable).parent}{os.pathsep}{env.get("PATH", "")}'
    no_pandas = str(cwd.parent / 'no-pandas')
    env['PYTHONPATH'] = os.pathsep.join([no_pandas, *filter(None, [env.get('PYTHONPATH')])])
    env.pop('CI', None)  # what a person's shell has
    return env


def _run_doc(commands: list[Command], cwd: Path) -> list[tuple[Command, int, str, float]]:
    env = _environment(cwd)
    results = []
    for command in commands:
        text = command.text
        if text.startswith('.venv/bin/'):
            text = text.removeprefix('.venv/bin/')
        began = time.perf_counter()
        try:
            proc = subprocess.run(
                ['bash', '-c', text],
                cwd=cwd,
                env=env,
                stdin=subprocess.DEVNULL,
                capture_output=True,
                text=True,
                timeout=COMMAND_TIMEOUT_S,
            )
            code, output = proc.returncode, (proc.stdout + proc.stderr)[-2000:]
        except subprocess.TimeoutExpired:
            code, output = -1, f'still running after {COMMAND_TIMEOUT_S} s'
        results.append((command, code, output, time.perf_counter() - began))
    return results


def test_every_readme_example_runs_here_and_only_the_synopsis_is_skipped() -> None:
    readme = [c for c in ALL if c.doc == 'README.md']
    assert len([c for c in readme if c.skip is None]) >= 8
    # the synopsis lines name their arguments in capitals; every other line is run
    synopsis = [c for c in readme if c.skip is not None]
    assert all(
        c.skip is not None and re.fullmatch(r'placeholder: [A-Z_]+', c.skip) for c in synopsis
    ), synopsis
    # and most commands of the documents run here, not only the README's
    runnable = [c for c in ALL if c.skip is None]
    assert len(runnable) >= 20, [(c.doc, c.line, c.skip) for c in ALL if c.skip]


def _readme_ci(command: Command) -> bool:
    """The CI examples (README's and docs/ci.md's, on fixtures/bags/ci.mcap): their verdicts are
    timings, so they run alone (quiet tests) rather than beside every other document's
    commands."""
    return command.doc in ('README.md', 'docs/ci.md') and (
        'ci.mcap' in command.text or 'runs/ci-' in command.text
    )


def test_every_command_in_the_readme_and_docs_runs_as_written(tmp_path: Path) -> None:
    by_doc: dict[str, list[Command]] = {}
    for command in ALL:
        if command.skip is None and not _readme_ci(command):
            by_doc.setdefault(command.doc, []).append(command)
    skipped = [c for c in ALL if c.skip is not None]
    for c in ALL:
        if _readme_ci(c):
            print(f'run alone: {c.doc}:{c.line}: {c.text}  (a CI example, timed)')
    for c in skipped:
        print(f'not run: {c.doc}:{c.line}: {c.text}  ({c.skip})')
    workspaces = {doc: _workspace(tmp_path / re.sub(r'\W', '_', doc)) for doc in by_doc}
    # one thread per document, the documents with a Ray sweep (the longest) first: the test
    # lasts as long as its longest document, not the sum of them
    order = sorted(by_doc, key=lambda doc: -sum(' sweep ' in c.text for c in by_doc[doc]))
    with ThreadPoolExecutor(max_workers=len(order)) as pool:
        futures = [pool.submit(_run_doc, by_doc[doc], workspaces[doc]) for doc in order]
        results = [r for f in futures for r in f.result()]
    failures = []
    for command, code, output, seconds in results:
        print(f'{seconds:6.1f} s  exit {code}  {command.doc}:{command.line}: {command.text}')
        if code not in command.expected:
            failures.append(
                f'{command.doc}:{command.line}: `{command.text}` exited {code}, '
                f'expected {command.expected}:\n{output}'
            )
    assert not failures, '\n\n'.join(failures)


def test_placeholders_and_exit_codes_are_read_from_the_document(tmp_path: Path) -> None:
    doc = tmp_path / 'doc.md'
    doc.write_text(
        'Text.\n\n'
        '    # placeholders: drive.mcap (your recording)\n'
        '    replaybench run drive.mcap -b hsv\n'
        '    replaybench run fixtures/bags/jpeg.mcap \\\n'
        '        --backend hsv --max-frames 3\n'
        '    replaybench compare runs/a runs/b  # exits 3: too few frames\n'
        '    replaybench compare runs/a runs/b --fail-if "p99_ms > +1%"  # exits 0, 1 or 3\n\n'
        '```\n'
        'replaybench run BAG... --backend NAME\n'
        'replaybench run $BAG --backend cuda\n'
        '```\n\n'
        '    # needs: an NVIDIA GPU\n'
        '    replaybench fixtures --out /tmp/big --frames 300 --size 1920x1080\n\n'
        'Text.\n\n'
        '    replaybench doctor\n',
        encoding='utf-8',
    )
    found = _commands_of(doc, 'doc.md')
    gpu = any(_gpu_available(name) for name in GPU_BACKENDS)
    every_gpu = all(_gpu_available(name) for name in GPU_BACKENDS)
    assert [(c.line, c.text, c.expected, c.skip is None) for c in found] == [
        (4, 'replaybench run drive.mcap -b hsv', (0,), False),
        (5, 'replaybench run fixtures/bags/jpeg.mcap --backend hsv --max-frames 3', (0,), True),
        (7, 'replaybench compare runs/a runs/b  # exits 3: too few frames', (3,), True),
        (
            8,
            'replaybench compare runs/a runs/b --fail-if "p99_ms > +1%"  # exits 0, 1 or 3',
            (0, 1, 3),
            True,
        ),
        (11, 'replaybench run BAG... --backend NAME', (0,), False),
        (12, 'replaybench run $BAG --backend cuda', (0,), False),
        (16, 'replaybench fixtures --out /tmp/big --frames 300 --size 1920x1080', (0,), gpu),
        (20, 'replaybench doctor', (0,) if every_gpu else (1,), True),
    ]


def test_a_block_may_declare_a_gpu_and_nothing_else(tmp_path: Path) -> None:
    doc = tmp_path / 'doc.md'
    doc.write_text('Text.\n\n    # needs: a quiet machine\n    replaybench backends\n')
    with pytest.raises(ValueError, match='unknown need'):
        _commands_of(doc, 'doc.md')


def test_the_default_install_leaves_out_what_only_development_needs() -> None:
    project = tomllib.loads((REPO / 'pyproject.toml').read_text(encoding='utf-8'))['project']
    core = {re.split(r'[\s<>=!~\[;]', d, maxsplit=1)[0].lower() for d in project['dependencies']}
    assert 'onnxruntime' in core
    assert not core & {'torch', 'playwright', 'mypy', 'ruff', 'pytest', 'scipy', 'ray', 'pandas'}
    extras = project['optional-dependencies']
    assert {'dev', 'train', 'gpu', 'sweep', 'pandas'} <= set(extras)
    dev = ' '.join(extras['dev'])
    for tool in ('pytest', 'ruff', 'mypy', 'playwright'):
        assert tool in dev
    # `make run` installs the core tier alone; `make test` the dev tier
    make = subprocess.run(
        ['make', '-n', '-B', 'run', 'VENV=/nonexistent/venv'],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    installs = [ln for ln in make.splitlines() if 'pip install' in ln and '--upgrade pip' not in ln]
    assert installs, make
    assert all(ln.rstrip().endswith('-e .') for ln in installs), installs
    make = subprocess.run(
        ['make', '-n', '-B', 'pytest', 'VENV=/nonexistent/venv'],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "-e '.[dev,train]'" in make


def test_the_readme_states_the_default_install_size_how_and_when_it_was_measured() -> None:
    readme = (REPO / 'README.md').read_text(encoding='utf-8')
    install = readme.split('## Usage')[0]
    sizes = [int(n) for n in re.findall(r'\| (\d+) MiB \|', install)]
    assert len(sizes) >= 2, install
    assert 'pip install .' in install
    assert 'make run' in install
    assert re.search(r'measured\s+\d{4}-\d{2}-\d{2}', install), install


@pytest.mark.quiet
def test_the_readme_ci_example_passes_the_same_code_and_fails_the_slower_backend(
    tmp_path: Path,
) -> None:
    """README's CI example on fixtures/bags/ci.mcap: three runs with --repeat, then an A/A
    compare that the document expects to exit 0 and a +30 % one that it expects to exit 1;
    both exit as stated."""
    ci = [c for c in ALL if _readme_ci(c) and c.doc == 'README.md']
    runs = [c for c in ci if c.text.startswith('replaybench run ')]
    compares = [c for c in ci if c.text.startswith('replaybench compare ')]
    assert len(runs) == 3
    assert all('--repeat ' in c.text and c.skip is None for c in runs)
    assert [c.expected for c in compares] == [(0,), (1,)]
    # a wrong verdict (the same code failed, the slower one passed) fails at once; an
    # inconclusive one (exit 3: the machine was too noisy for the data to decide, as the
    # README says it may be) is tried again, at most three times in all
    tries = []
    for attempt in range(3):
        results = _run_doc(ci, _workspace(tmp_path / str(attempt)))
        codes = [code for _, code, _, _ in results]
        tries.append([(c.text, code, out) for c, code, out, _ in results])
        assert codes[:3] == [0, 0, 0], tries[-1]
        assert codes[3] != 1, tries[-1]  # the same code never fails the gate
        assert codes[4] != 0, tries[-1]  # a +30 % regression never passes it
        if codes == [0, 0, 0, 0, 1]:
            break
    assert codes == [0, 0, 0, 0, 1], tries


@pytest.mark.quiet
def test_the_ci_page_example_gates_two_runs_of_the_same_code_and_publishes(tmp_path: Path) -> None:
    """docs/ci.md's example on fixtures/bags/ci.mcap, run alone: each command exits as the page
    says (the A/A gate passes or, with --allow-inconclusive, is let through)."""
    ci = [c for c in ALL if _readme_ci(c) and c.doc == 'docs/ci.md']
    assert ci
    assert all(c.skip is None for c in ci)
    results = _run_doc(ci, _workspace(tmp_path))
    failed = [(c.text, code, out) for c, code, out, _ in results if code not in c.expected]
    assert not failed, failed
