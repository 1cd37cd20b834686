"""Every module of replaybench stays small enough to read: none over 650 lines."""

from __future__ import annotations

from pathlib import Path

import replaybench

LIMIT = 650
PACKAGE = Path(replaybench.__file__).parent


def test_no_module_of_replaybench_is_over_650_lines():
    sizes = {
        str(path.relative_to(PACKAGE)): len(path.read_text(encoding='utf-8').splitlines())
        for path in sorted(PACKAGE.rglob('*.py'))
    }
    assert len(sizes) > 100
    assert 'sources/mcap.py' in sizes
    assert {name: n for name, n in sizes.items() if n > LIMIT} == {}
