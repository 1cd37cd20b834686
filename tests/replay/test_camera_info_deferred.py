"""A run whose backends never read a frame's camera info (``reads_camera_info`` False) reads
the bag's CameraInfo messages after its passes, and writes the same outputs.mcap as a run
whose backend reads them before its first frame."""

from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from mcap.reader import make_reader

from replaybench.backends.null import NullBackend
from replaybench.decode import camera_info as camera_info_module
from replaybench.replay import output as output_module
from replaybench.replay import runner as runner_module
from replaybench.replay.runner import RunConfig, run_benchmark

if TYPE_CHECKING:
    from collections.abc import Callable

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


def _interrupted_copy(
    out: Path, monkeypatch: pytest.MonkeyPatch, interrupt: Callable[[], None]
) -> tuple[dict[str, Any], list[Any]]:
    """A run whose camera infos are read after the passes, ``interrupt`` called at the third
    one read: run.json and outputs.mcap's messages."""
    real = camera_info_module.decode_camera_info
    reads: list[int] = []

    def decode(raw: object) -> object:
        reads.append(1)
        if len(reads) == 3:
            interrupt()
        return real(raw)  # type: ignore[arg-type]

    monkeypatch.setattr(camera_info_module, 'decode_camera_info', decode)
    _Silent.events, _Silent.infos = [], []
    stop = threading.Event()
    outcome = run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=out, report=False, warmup=0),
        backend_factory=lambda name, options: _Silent(options),
        stop=stop,
    )
    assert outcome.status == 'interrupted'
    assert outcome.run_dir is not None
    assert len(_Silent.events) > 2  # every frame was replayed before
    with (outcome.run_dir / 'outputs.mcap').open('rb') as f:
        reader = make_reader(f)
        messages = list(reader.iter_messages())
        summary = reader.get_summary()
    assert not list(outcome.run_dir.glob('*.part'))
    assert summary is not None  # a finished MCAP, its camera info channel made before the passes
    assert '/camera/camera_info' in {c.topic for c in summary.channels.values()}
    return json.loads((outcome.run_dir / 'run.json').read_text()), messages


def test_a_ctrl_c_while_the_camera_infos_are_copied_ends_the_run_as_interrupted(
    tmp_path, monkeypatch
):
    def ctrl_c() -> None:
        raise KeyboardInterrupt

    run, messages = _interrupted_copy(tmp_path / 'run', monkeypatch, ctrl_c)
    assert run['status'] == 'interrupted'
    frames = [m for m in messages if m[1].topic.startswith('/replaybench/')]
    assert len(frames) == len(_Silent.events)
    # they are all read before the first is written: none was copied
    assert not [m for m in messages if m[1].topic == '/camera/camera_info']


def test_a_stop_set_while_the_camera_infos_are_copied_ends_the_run_as_interrupted(
    tmp_path, monkeypatch
):
    stops: list[threading.Event] = []
    real_run = output_module.copy_camera_infos

    def copy(inputs: object, writer: object, stop: threading.Event | None = None) -> bool:
        assert stop is not None
        stops.append(stop)
        return real_run(inputs, writer, stop)  # type: ignore[arg-type]

    monkeypatch.setattr(runner_module, 'copy_camera_infos', copy)
    run, messages = _interrupted_copy(tmp_path / 'run', monkeypatch, lambda: stops[0].set())
    assert run['status'] == 'interrupted'
    assert len(stops) == 1
    assert not [m for m in messages if m[1].topic == '/camera/camera_info']
