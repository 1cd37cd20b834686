"""Backend registry: built-ins, entry point discovery, broken plugins, clear errors."""

from __future__ import annotations

import sys
import textwrap
from importlib.metadata import EntryPoint
from typing import TYPE_CHECKING

import pytest

import replaybench.backends as registry
from replaybench.backends import (
    BUILTIN_BACKENDS,
    ENTRY_POINT_GROUP,
    Availability,
    backend_names,
    backend_table,
    get_backend,
)
from replaybench.backends.hsv import HsvBackend
from replaybench.backends.null import NullBackend
from replaybench.errors import BackendUnavailableError, UsageError

if TYPE_CHECKING:
    from collections.abc import Iterator
    from pathlib import Path

PLUGIN = """
from typing import Any, ClassVar

from replaybench.backends.base import Availability
from replaybench.types import BackendResult


class ToyBackend:
    name: ClassVar[str] = 'toy'
    description: ClassVar[str] = 'a toy backend'

    def __init__(self, options):
        self.options = options

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=True)

    def open(self) -> None: ...

    def detect(self, frame) -> BackendResult:
        return BackendResult(())

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None: ...


class NoGpuBackend(ToyBackend):
    name: ClassVar[str] = 'nogpu'

    @classmethod
    def available(cls) -> Availability:
        return Availability(ok=False, reason='no CUDA device')


class ExplodingBackend(ToyBackend):
    name: ClassVar[str] = 'boom'

    @classmethod
    def available(cls) -> Availability:
        raise RuntimeError('driver crashed')


class Misnamed(ToyBackend):
    name: ClassVar[str] = 'something-else'


NOT_A_CLASS = 42
"""


@pytest.fixture
def plugin_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A real importable module holding third-party backend classes."""
    name = f'rb_toy_plugin_{tmp_path.name.replace("-", "_")}'
    (tmp_path / f'{name}.py').write_text(PLUGIN, encoding='utf-8')
    monkeypatch.syspath_prepend(str(tmp_path))
    yield name
    sys.modules.pop(name, None)


def entry_points(monkeypatch: pytest.MonkeyPatch, **targets: str) -> None:
    """Install entry points name -> 'module:attr' in place of the installed distributions'."""
    eps = [EntryPoint(name=n, value=v, group=ENTRY_POINT_GROUP) for n, v in targets.items()]
    monkeypatch.setattr(registry, '_entry_points', lambda: sorted(eps, key=lambda e: e.name))


BUILTINS = [
    'null',
    'hsv',
    'onnx-cpu',
    'recorded',
    'busy',
    'cuda',
    'tensorrt',
    'hsv-cuda',
    'hsv-seg',
    'onnx-seg',
    'onnx-stereo',
    'cuda-stereo',
    'tensorrt-stereo',
    'apriltag',
    'aruco',
    'sgbm',
    'bm',
]


def test_builtin_backends_are_listed_in_registry_order() -> None:
    assert list(BUILTIN_BACKENDS) == BUILTINS
    assert BUILTIN_BACKENDS['hsv'] == 'replaybench.backends.hsv:HsvBackend'
    assert backend_names() == BUILTINS
    assert get_backend('hsv') is HsvBackend
    assert get_backend('null') is NullBackend


def test_unknown_backend_is_a_usage_error_listing_the_names(
    monkeypatch: pytest.MonkeyPatch, plugin_module: str
) -> None:
    entry_points(monkeypatch, toy=f'{plugin_module}:ToyBackend')
    with pytest.raises(
        UsageError,
        match=r"unknown backend 'yolo'; known backends: null, hsv, .*aruco, sgbm, bm, toy",
    ):
        get_backend('yolo')


def test_entry_point_backends_are_discovered(
    monkeypatch: pytest.MonkeyPatch, plugin_module: str
) -> None:
    entry_points(monkeypatch, toy=f'{plugin_module}:ToyBackend')
    assert backend_names() == [*BUILTINS, 'toy']
    cls = get_backend('toy')
    assert cls.__name__ == 'ToyBackend'
    assert cls.__module__ == plugin_module
    rows = {row.name: row for row in backend_table()}
    assert rows['toy'].availability == Availability(ok=True)
    assert rows['toy'].description == 'a toy backend'
    assert rows['toy'].origin == f'entry point {plugin_module}:ToyBackend'
    assert rows['hsv'].origin == rows['null'].origin == 'built-in'


def test_broken_entry_points_are_listed_as_unavailable_with_the_reason(
    monkeypatch: pytest.MonkeyPatch, plugin_module: str
) -> None:
    entry_points(
        monkeypatch,
        gone='rb_no_such_module_anywhere:Backend',
        noattr=f'{plugin_module}:Missing',
        number=f'{plugin_module}:NOT_A_CLASS',
        misnamed=f'{plugin_module}:Misnamed',
        nogpu=f'{plugin_module}:NoGpuBackend',
        boom=f'{plugin_module}:ExplodingBackend',
        toy=f'{plugin_module}:ToyBackend',
    )
    rows = {row.name: row for row in backend_table()}
    reasons = {name: row.availability.reason for name, row in rows.items()}
    assert not any(rows[n].availability.ok for n in ('gone', 'noattr', 'number', 'misnamed'))
    assert 'ModuleNotFoundError' in reasons['gone']
    assert 'AttributeError' in reasons['noattr']
    assert 'is not a class' in reasons['number']
    assert "declares name 'something-else'" in reasons['misnamed']
    assert rows['nogpu'].availability == Availability(ok=False, reason='no CUDA device')
    assert reasons['boom'] == 'available() failed: RuntimeError: driver crashed'
    assert rows['toy'].availability.ok
    assert rows['hsv'].availability.ok
    with pytest.raises(BackendUnavailableError, match=r"backend 'gone': cannot load"):
        get_backend('gone')


def test_an_entry_point_cannot_shadow_a_builtin(
    monkeypatch: pytest.MonkeyPatch, plugin_module: str
) -> None:
    entry_points(monkeypatch, hsv=f'{plugin_module}:ToyBackend')
    assert get_backend('hsv') is HsvBackend
    assert backend_names() == BUILTINS
    shadow = [row for row in backend_table() if row.origin.startswith('entry point')]
    assert len(shadow) == 1
    assert shadow[0].name == 'hsv'
    assert 'taken by a built-in backend' in shadow[0].availability.reason


def test_invalid_entry_point_names_are_rejected(
    monkeypatch: pytest.MonkeyPatch, plugin_module: str
) -> None:
    entry_points(monkeypatch, **{'bad name': f'{plugin_module}:ToyBackend'})
    assert backend_names() == BUILTINS
    (row,) = [row for row in backend_table() if row.name == 'bad name']
    assert 'invalid backend name' in row.availability.reason


def test_installed_distributions_register_backends_through_the_entry_point_group(
    tmp_path: Path, plugin_module: str
) -> None:
    dist = tmp_path / 'rb_toy_dist-1.2.dist-info'
    dist.mkdir()
    (dist / 'METADATA').write_text(
        'Metadata-Version: 2.1\nName: rb-toy-dist\nVersion: 1.2\n', encoding='utf-8'
    )
    (dist / 'entry_points.txt').write_text(
        textwrap.dedent(f"""
            [{ENTRY_POINT_GROUP}]
            toy = {plugin_module}:ToyBackend
            """),
        encoding='utf-8',
    )
    assert 'toy' in backend_names()
    assert get_backend('toy').__name__ == 'ToyBackend'
    (row,) = [row for row in backend_table() if row.name == 'toy']
    assert row.origin == f'entry point {plugin_module}:ToyBackend (rb-toy-dist 1.2)'
