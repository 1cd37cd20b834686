"""docs/api.md: every ``python`` example runs as written (``python skip`` ones are not run)."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / 'docs' / 'api.md'
_BLOCK = re.compile(r'^```(?P<info>[^\n]*)\n(?P<code>.*?)^```$', re.MULTILINE | re.DOTALL)


def _examples() -> list[tuple[int, str]]:
    text = DOC.read_text(encoding='utf-8')
    found = []
    for match in _BLOCK.finditer(text):
        if match['info'].strip() == 'python':
            line = text.count('\n', 0, match.start()) + 1
            found.append((line, match['code']))
    return found


def test_the_page_has_examples_to_run():
    assert len(_examples()) >= 6


@pytest.mark.parametrize(
    ('line', 'code'), _examples(), ids=lambda v: f'line{v}' if isinstance(v, int) else ''
)
def test_each_example_runs_from_the_repository_root(line, code, tmp_path, monkeypatch):
    (tmp_path / 'fixtures').symlink_to(REPO / 'fixtures', target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    shown = io.StringIO()
    with contextlib.redirect_stdout(shown):
        exec(compile(code, f'{DOC}:{line}', 'exec'), {'__name__': '__docs__'})
    assert shown.getvalue(), f'the example at line {line} printed nothing'
