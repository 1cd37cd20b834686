"""docs/examples/gpu_tag_backend.py, the GPU tag detector plugin example, registered through an
entry point and replayed over a tag bag. There is no GPU here: its one device call
(``find_tags``) is done by OpenCV's ArUco detector on the CPU, the only part replaced."""

from __future__ import annotations

import importlib.util
import json
import sys
from importlib.metadata import EntryPoint
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import replaybench.backends as registry
from replaybench.app.run import run_benchmark, run_config
from replaybench.backends import ENTRY_POINT_GROUP, backend_table
from replaybench.backends.base import backend_traits
from replaybench.fiducials.detect import RawTag
from replaybench.fixtures.tags import write_tag_mcap

EXAMPLE = Path(__file__).resolve().parents[2] / 'docs' / 'examples' / 'gpu_tag_backend.py'


class _CpuQuads:
    """Stands in for the GPU binding: OpenCV's ArUco tag36h11 detector with sub-pixel
    corner refinement, as the aruco backend runs it by default."""

    def __init__(self) -> None:
        import cv2

        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        self.detector = cv2.aruco.ArucoDetector(dictionary, params)

    def __call__(self, gray: Any) -> list[RawTag]:
        corners, ids, _ = self.detector.detectMarkers(gray)
        if ids is None:
            return []
        return [
            RawTag(int(i), tuple(map(tuple, np.asarray(q).reshape(4, 2))))  # type: ignore[arg-type]
            for q, i in zip(corners, ids.reshape(-1), strict=True)
        ]


@pytest.fixture
def plugin(monkeypatch: pytest.MonkeyPatch) -> type:
    """The example as module ``gpu_tag_example``, its device call replaced, registered as the
    entry point ``gpu-tags``."""
    spec = importlib.util.spec_from_file_location('gpu_tag_example', EXAMPLE)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, 'gpu_tag_example', module)
    spec.loader.exec_module(module)
    cls: Any = module.GpuTagBackend
    quads = _CpuQuads()
    monkeypatch.setattr(cls, 'available', classmethod(lambda c: registry.Availability(ok=True)))
    monkeypatch.setattr(cls, 'open', lambda self: None)
    monkeypatch.setattr(cls, 'find_tags', lambda self, gray: quads(gray))
    entry = EntryPoint(
        name='gpu-tags', value='gpu_tag_example:GpuTagBackend', group=ENTRY_POINT_GROUP
    )
    monkeypatch.setattr(registry, '_entry_points', lambda: [entry])
    return cls  # type: ignore[no-any-return]


def test_the_example_without_its_binding_is_listed_unavailable_with_the_reason(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    spec = importlib.util.spec_from_file_location('gpu_tag_example_bare', EXAMPLE)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, 'gpu_tag_example_bare', module)
    spec.loader.exec_module(module)
    entry = EntryPoint(
        name='gpu-tags', value='gpu_tag_example_bare:GpuTagBackend', group=ENTRY_POINT_GROUP
    )
    monkeypatch.setattr(registry, '_entry_points', lambda: [entry])
    row = next(r for r in backend_table() if r.name == 'gpu-tags')
    assert not row.availability.ok
    assert 'cuapriltags' in row.availability.reason


def test_the_gpu_tag_plugin_example_replays_and_is_scored_like_a_built_in(
    plugin: type, tmp_path: Path
) -> None:
    assert backend_traits(plugin).device == 'cuda'
    bag = write_tag_mcap(tmp_path / 'tags.mcap', 4)
    out = tmp_path / 'run'
    config = run_config(
        bag,
        backends=['gpu-tags', 'aruco'],
        out=out,
        warmup=0,
        tag_size=0.16,
        tag_sizes='14=0.2,3=0.1',
    )
    outcome = run_benchmark(config)
    assert outcome.status == 'complete'
    rows = {row.backend: row for row in outcome.run.summary_rows}
    plugin_acc, aruco_acc = rows['gpu_tags'].tag_accuracy, rows['aruco'].tag_accuracy
    assert plugin_acc is not None
    assert aruco_acc is not None
    assert plugin_acc.recall == 1.0
    # the same detector on the CPU: the same tags and poses as the aruco backend
    assert plugin_acc.corner_rmse_px == pytest.approx(aruco_acc.corner_rmse_px, rel=1e-9)
    assert plugin_acc.rot_err_deg == pytest.approx(aruco_acc.rot_err_deg, rel=1e-9)
    run = json.loads((out / 'run.json').read_text())
    info = next(b for b in run['backends'] if b['name'] == 'gpu-tags')['info']
    assert info['binding'] == 'cuapriltags'
