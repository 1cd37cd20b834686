"""Streaming scores of recorded outputs (the ``recorded`` backend): on the recording's clock,
from its log times, at any rate. The output in use at each frame's log time is found here from
frames.csv's log times alone, independently of the engine."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.replay.streaming import REFUSED_AT_MAX

REPO = Path(__file__).resolve().parents[2]


def _frames(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / 'frames.csv').open(newline='') as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize(
    ('bag', 'metric', 'offline'),
    [
        ('bags/live_detections.mcap', 'streaming_map50', 'map50'),
        ('tags/live_tags.mcap', 'streaming_tag_recall', 'tag_recall'),
    ],
)
def test_recorded_outputs_are_picked_by_their_log_times_even_at_max_rate(
    tmp_path: Path, bag: str, metric: str, offline: str
) -> None:
    outcome = run_benchmark(
        RunConfig(inputs=[REPO / 'fixtures' / bag], backends=['recorded'], out_dir=tmp_path / 'r')
    )
    assert REFUSED_AT_MAX not in outcome.run.warnings
    frames = _frames(tmp_path / 'r')
    outputs = [
        (int(f['output_log_time_ns']), int(f['log_time_ns']))
        for f in frames
        if f['output_log_time_ns']
    ]
    aged = 0
    for f in frames:
        released = int(f['log_time_ns'])
        ready = [(t, logged) for t, logged in outputs if t <= released]
        expected = '' if not ready else f'{(released - max(ready)[1]) / 1e6:.4f}'
        assert f['output_age_ms'] == expected, f['seq']
        aged += bool(ready)
    # the outputs were logged after their images: the first frames have none in use yet
    assert 0 < aged < len(frames)
    [row] = outcome.summaries
    assert row.metric(offline) is not None
    assert row.metric(metric) is not None
    assert row.metric(metric) != row.metric(offline)
