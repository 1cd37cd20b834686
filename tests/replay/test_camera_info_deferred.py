"""A run whose backends never read a frame's camera info (``reads_camera_info`` False) reads
the bag's CameraInfo messages after its passes, and writes the same outputs.mcap as a run
whose backend reads them before its first frame."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

from replaybench.backends.null import NullBackend
from replaybench.decode import camera_info as camera_info_module
from replaybench.replay.runner import RunConfig, run_benchmark

if TYPE_CHECKING:
    import pytest

    from replaybench.types import BackendResult, Frame

RAW = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


class _Silent(NullBackend):
    """The null backend (it never reads the camera info), logging its frames."""

    events: ClassVar[list[str]] = []
    infos: ClassVar[list[object]] = []

    def detect(self, frame: Frame) -> BackendResult:
        self.events.append('frame')
        self.infos.append(frame.camera_info)
        return super().detect(frame)


class _Reading(_Silent):
    """The same, declaring that it reads a frame's camera info."""

    reads_camera_info: ClassVar[bool] = True


def _run(backend: type[_Silent], out: Path, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    events: list[str] = []
    real = camera_info_module.decode_camera_info

    def decode(raw: object) -> object:
        events.append('info')
        return real(raw)  # type: ignore[arg-type]

    monkeypatch.setattr(camera_info_module, 'decode_camera_info', decode)
    backend.events, backend.infos = events, []
    run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=out, report=False, warmup=0),
        backend_factory=lambda name, options: backend(options),
    )
    return events


def test_camera_infos_are_read_after_the_passes_when_no_backend_reads_them(tmp_path, monkeypatch):
    events = _run(_Silent, tmp_path / 'silent', monkeypatch)
    last_frame = max(i for i, e in enumerate(events) if e == 'frame')
    assert events.index('info') < last_frame  # the first one, for its channel's place
    assert events[: events.index('frame')].count('info') == 1
    assert events.count('info') > 2  # and all of them after the passes
    assert set(_Silent.infos) == {None}


def test_a_backend_that_reads_camera_infos_gets_them_and_the_outputs_are_the_same(
    tmp_path, monkeypatch
):
    silent = tmp_path / 'silent'
    _run(_Silent, silent, monkeypatch)
    events = _run(_Reading, tmp_path / 'reading', monkeypatch)
    first_frame = events.index('frame')
    assert events[:first_frame].count('info') == events.count('info') > 2
    assert all(info is not None for info in _Reading.infos)
    detections = (silent / 'outputs.mcap').read_bytes()
    assert detections == (tmp_path / 'reading' / 'outputs.mcap').read_bytes()
    assert b'/camera/camera_info' in detections
