"""The default install (``pip install .``) stays small: what its dependencies hold on disk.

The dependency closure of replaybench without extras is walked through the installed
distributions' metadata (the test environment holds every one of them), and the files each
records are measured as they lie on disk, bytecode included. README.md states the size of the
whole virtual environment, which adds the interpreter's links, pip and setuptools (about
25 MiB) and replaybench itself (about 5 MiB).
"""

from __future__ import annotations

import importlib.metadata as md
import re

from packaging.requirements import Requirement

MIB = 2**20
#: the issue's bound for the whole virtual environment, less 40 MiB for pip, setuptools and
#: replaybench itself
CLOSURE_LIMIT_MIB = 450 - 40
#: what only development, training, GPUs or clusters need: never in the default install
HEAVY = {'torch', 'pandas', 'playwright', 'mypy', 'ruff', 'pytest', 'scipy', 'ray', 'cupy'}


def _name(text: str) -> str:
    return re.sub(r'[-_.]+', '-', text).lower()


def _default_closure() -> dict[str, md.Distribution]:
    """Every distribution ``pip install replaybench`` installs (no extras), by name."""
    found: dict[str, md.Distribution] = {}
    todo = [Requirement(r) for r in md.requires('replaybench') or ()]
    while todo:
        req = todo.pop()
        if req.marker is not None and not req.marker.evaluate({'extra': ''}):
            continue  # an extra's requirement, or another platform's
        name = _name(req.name)
        if name in found:
            continue
        found[name] = dist = md.distribution(req.name)
        todo.extend(Requirement(r) for r in dist.requires or ())
    return found


def _size(dist: md.Distribution) -> int:
    total = 0
    for file in dist.files or ():
        path = dist.locate_file(file)
        if path.is_file():  # type: ignore[attr-defined]
            total += path.stat().st_size  # type: ignore[attr-defined]
    return total


def test_the_default_install_pulls_in_nothing_heavy() -> None:
    closure = _default_closure()
    assert {'onnxruntime', 'opencv-python-headless', 'numpy', 'mcap', 'rosbags'} <= set(closure)
    assert not {n for n in closure if n.split('-')[0] in HEAVY}, sorted(closure)


def test_the_default_install_fits_the_size_bound() -> None:
    sizes = {name: _size(dist) for name, dist in _default_closure().items()}
    total = sum(sizes.values())
    largest = sorted(sizes.items(), key=lambda kv: -kv[1])[:5]
    assert total / MIB <= CLOSURE_LIMIT_MIB, [(n, round(s / MIB)) for n, s in largest]
    # measured, not assumed: the big three are there and weigh what the README says
    assert sizes['opencv-python-headless'] > 100 * MIB
