"""The run record is built typed, once, in memory: what a run returns is what it wrote, without
reading its folder back or passing through JSON."""

from __future__ import annotations

from pathlib import Path

import pytest

import replaybench as rb
from replaybench.results import io as results_io
from replaybench.results import records as results_records
from replaybench.results.io import from_json, read_peak_result, to_json
from replaybench.results.model import PeakResult, RunResult

BAGS = Path(__file__).resolve().parents[2] / 'fixtures' / 'bags'
RAW = BAGS / 'rgb8_raw.mcap'
TWO = BAGS / 'two_camera.mcap'


def _refuse(*_args: object, **_kwargs: object) -> None:
    msg = 'a run must not read back or round-trip what it has just built'
    raise AssertionError(msg)


@pytest.fixture
def no_reading_back(monkeypatch: pytest.MonkeyPatch) -> None:
    """Reading run.json or frames.csv, and turning documents into the model, fail."""
    monkeypatch.setattr(results_io, 'read_run_result', _refuse)
    monkeypatch.setattr(results_io, 'from_document', _refuse)
    monkeypatch.setattr(results_io, 'from_json', _refuse)
    monkeypatch.setattr(results_records, 'read_frames_csv', _refuse)
    monkeypatch.setattr('replaybench.results.folder.read_run_result', _refuse)
    monkeypatch.setattr('replaybench.results.folder.read_frames_csv', _refuse)


@pytest.mark.usefixtures('no_reading_back')
def test_a_run_into_a_folder_returns_what_it_wrote_without_reading_it_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    result = rb.run(TWO, backends=['hsv', 'null'], out=tmp_path / 'run')
    assert (tmp_path / 'run' / 'report.html').is_file()  # drawn from the frames in memory
    monkeypatch.undo()
    assert result == rb.load_run(tmp_path / 'run')
    assert result.frame_records == rb.load_run(tmp_path / 'run').frame_records


@pytest.mark.usefixtures('no_reading_back')
def test_a_run_kept_in_memory_holds_the_values_its_files_would_hold(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    result = rb.run(RAW, backends=['hsv', 'onnx-cpu'], max_frames=6)
    monkeypatch.undo()
    assert isinstance(result, RunResult)
    assert result.summary_rows[0].accuracy is not None  # scored against the ground truth topic
    assert result.agreement  # two backends
    assert result == from_json(RunResult, to_json(result), where='run')


@pytest.mark.usefixtures('no_reading_back')
def test_a_peak_search_returns_its_peak_json_without_reading_it_or_its_trials_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    result = rb.peak(RAW, backend='null', out=tmp_path / 'peak', max_hz=40, refine_steps=0)
    assert (tmp_path / 'peak' / 'peak.html').is_file()  # drawn from the record in memory
    monkeypatch.undo()
    assert result == read_peak_result(tmp_path / 'peak' / 'peak.json')
    assert result == from_json(PeakResult, to_json(result), where='peak')
