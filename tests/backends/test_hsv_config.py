"""The hsv backend's TOML configuration: defaults, docs, valid files and clear errors."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

import pytest

from replaybench.backends import BackendOptions
from replaybench.backends.hsv import (
    DEFAULT_CLASSES,
    ColorClass,
    DetectorParams,
    HsvBackend,
    HsvConfig,
    config_to_toml,
    default_config_toml,
    load_config,
    parse_config,
)
from replaybench.errors import BackendError

DOCS = Path(__file__).resolve().parents[2] / 'docs'
REGENERATE = (
    ".venv/bin/python -c 'from replaybench.backends.hsv import default_config_toml; "
    'print(default_config_toml(), end="")\' > docs/hsv-default.toml'
)

Scene = Any


def test_default_classes_are_red_green_blue_yellow_in_that_order() -> None:
    assert [c.name for c in HsvConfig().classes] == ['red', 'green', 'blue', 'yellow']
    assert len(DEFAULT_CLASSES[0].ranges) == 2  # red wraps around hue 0
    assert HsvConfig().detector == DetectorParams(100.0, 5, 1, 1)


def test_docs_default_toml_is_the_built_in_defaults() -> None:
    text = (DOCS / 'hsv-default.toml').read_text(encoding='utf-8')
    assert text == default_config_toml(), f'regenerate with: {REGENERATE}'
    assert load_config(DOCS / 'hsv-default.toml') == HsvConfig()


def test_backends_doc_shows_the_same_defaults() -> None:
    text = (DOCS / 'backends.md').read_text(encoding='utf-8')
    blocks = re.findall(r'```toml\n(.*?)```', text, flags=re.DOTALL)
    assert default_config_toml() in blocks


def test_config_round_trips_through_toml() -> None:
    config = HsvConfig(
        (
            ColorClass('orange "safety"', (((10, 150, 100), (20, 255, 255)),)),
            ColorClass('magenta', (((140, 90, 50), (165, 255, 250)),)),
        ),
        DetectorParams(min_area=12.5, kernel=3, open_iterations=0, close_iterations=2),
    )
    assert parse_config(tomllib.loads(config_to_toml(config))) == config


def test_a_valid_file_sets_classes_and_detector(tmp_path: Path, scene: type[Scene]) -> None:
    path = tmp_path / 'hsv.toml'
    path.write_text(
        '[detector]\nmin_area = 20\nkernel = 3\n\n'
        '[[classes]]\nname = "cone"\nranges = [[[0, 100, 70], [10, 255, 255]]]\n\n'
        '[[classes]]\nname = "ball"\nranges = [[[100, 100, 70], [130, 255, 255]]]\n',
        encoding='utf-8',
    )
    backend = HsvBackend(BackendOptions(config=path))
    assert [c.name for c in backend.config.classes] == ['cone', 'ball']
    assert backend.config.detector == DetectorParams(20.0, 3, 1, 1)
    backend.open()
    frame = scene().rect('blue', 10, 10, 20, 20).rect('red', 100, 100, 140, 130).frame()
    found = backend.detect(frame).detections
    assert [(d.class_index, d.label) for d in found] == [(0, 'cone'), (1, 'ball')]
    assert backend.info()['config'] == str(path)


def test_a_file_with_only_a_detector_table_keeps_the_default_classes(tmp_path: Path) -> None:
    path = tmp_path / 'hsv.toml'
    path.write_text('[detector]\nmin_area = 5.5\n', encoding='utf-8')
    config = load_config(path)
    assert config.classes == DEFAULT_CLASSES
    assert config.detector.min_area == 5.5


def test_a_single_red_range_misses_the_far_side_of_the_hue_wrap(
    tmp_path: Path, scene: type[Scene]
) -> None:
    path = tmp_path / 'hsv.toml'
    path.write_text('[[classes]]\nname = "red"\nranges = [[[0, 100, 70], [10, 255, 255]]]\n')
    s = scene().rect((0, 40, 230), 20, 20, 80, 60).rect((60, 0, 230), 180, 120, 260, 200)
    backend = HsvBackend(BackendOptions(config=path))
    backend.open()
    found = backend.detect(s.frame()).detections
    assert [(d.x0, d.y0) for d in found] == [(20.0, 20.0)]


INVALID = [
    ('detector.x', '[detector]\nmin_aera = 10\n', r"\[detector\]: unknown key 'min_aera'"),
    ('top', 'colours = 1\n', r"top level: unknown key 'colours'"),
    (
        'kernel',
        '[detector]\nkernel = 4\n',
        r'\[detector\] kernel: must be an odd integer >= 1, got 4',
    ),
    ('area', '[detector]\nmin_area = -1\n', r'\[detector\] min_area: must be >= 0'),
    ('area str', '[detector]\nmin_area = "big"\n', r'min_area: expected a finite number'),
    ('iterations', '[detector]\nclose_iterations = 1.5\n', r'close_iterations: must be an integer'),
    (
        'wrap',
        '[[classes]]\nname = "red"\nranges = [[[170, 100, 70], [10, 255, 255]]]\n',
        r'classes\[0\]\.ranges\[0\]: lower hue 170 > upper hue 10; .*split in two ranges',
    ),
    (
        'saturation',
        '[[classes]]\nname = "x"\nranges = [[[0, 300, 70], [10, 255, 255]]]\n',
        r'classes\[0\]\.ranges\[0\]\[0\]: saturation 300 is outside 0\.\.255',
    ),
    (
        'hue',
        '[[classes]]\nname = "x"\nranges = [[[0, 0, 0], [181, 255, 255]]]\n',
        r'classes\[0\]\.ranges\[0\]\[1\]: hue 181 is outside 0\.\.180',
    ),
    (
        'triple',
        '[[classes]]\nname = "x"\nranges = [[[0, 0], [10, 255, 255]]]\n',
        r'ranges\[0\]\[0\]: expected \[H, S, V\] with 3 integers',
    ),
    ('no ranges', '[[classes]]\nname = "x"\nranges = []\n', r'classes\[0\]\.ranges: expected a'),
    ('no name', '[[classes]]\nranges = [[[0, 0, 0], [10, 255, 255]]]\n', r'classes\[0\]\.name'),
    (
        'duplicate',
        '[[classes]]\nname = "a"\nranges = [[[0, 0, 0], [1, 1, 1]]]\n' * 2,
        r"classes\[1\]\.name: duplicate class name 'a'",
    ),
    ('class key', '[[classes]]\nname = "a"\nrange = 1\n', r"classes\[0\]: unknown key 'range'"),
    ('syntax', '[detector\nkernel = 3\n', r'not valid TOML'),
]


@pytest.mark.parametrize(('case', 'text', 'message'), INVALID, ids=[c[0] for c in INVALID])
def test_an_invalid_file_names_file_key_and_problem(
    tmp_path: Path, case: str, text: str, message: str
) -> None:
    path = tmp_path / f'{case.replace(" ", "_")}.toml'
    path.write_text(text, encoding='utf-8')
    with pytest.raises(BackendError, match=message) as info:
        HsvBackend(BackendOptions(config=path))
    assert str(info.value).startswith(f'{path}: ')


def test_a_missing_file_is_a_clear_backend_error(tmp_path: Path) -> None:
    path = tmp_path / 'absent.toml'
    with pytest.raises(BackendError, match=r'absent\.toml: cannot read hsv config'):
        load_config(path)


def test_backend_options_override_detector_keys() -> None:
    backend = HsvBackend(BackendOptions(extra={'min_area': '7.5', 'close_iterations': '0'}))
    assert backend.config.detector == DetectorParams(7.5, 5, 1, 0)


@pytest.mark.parametrize(
    ('extra', 'message'),
    [
        ({'minarea': '3'}, r"unknown option 'minarea' \(known: close_iterations, kernel"),
        ({'kernel': 'five'}, r"option kernel='five' is not a number"),
        ({'kernel': '2'}, r'kernel: must be an odd integer >= 1, got 2'),
    ],
)
def test_bad_backend_options_are_backend_errors(extra: dict[str, str], message: str) -> None:
    with pytest.raises(BackendError, match=message):
        HsvBackend(BackendOptions(extra=extra))
