"""Streaming scores of a stereo backend on the virtual clock: sgbm, made to take a set time per
pair, on the stereo fixture at its recorded 10 Hz; the expected figures are the bare matcher's
disparity of the pair in use at each release scored against that pair's truth, counted here."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np
import pytest

from replaybench.backends.base import BackendOptions
from replaybench.backends.sgbm import SgbmBackend
from replaybench.fixtures.stereo import render_stereo, write_stereo_mcap
from replaybench.replay import VirtualClock
from replaybench.replay.rate import parse_rate
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.replay.sync import parse_sync
from replaybench.stereo import DisparityCounts, Matcher, score_disparity

if TYPE_CHECKING:
    from pathlib import Path

    from replaybench.backends.base import Backend
    from replaybench.replay.runner import RunOutcome
    from replaybench.types import BackendResult, FrameSet

PAIRS = 6


class TimedSgbm(SgbmBackend):
    """sgbm whose every pair takes ``delay_s`` on the virtual clock."""

    def __init__(self, clock: VirtualClock, delay_s: float) -> None:
        super().__init__(BackendOptions())
        self.clock, self.delay_s = clock, delay_s

    def detect(self, frame_set: FrameSet) -> BackendResult:
        result = super().detect(frame_set)
        self.clock.advance(self.delay_s)
        return result


def _run(tmp_path: Path, delay_s: float, rate: str = 'recorded') -> RunOutcome:
    clock = VirtualClock()
    bag = write_stereo_mcap(tmp_path / f'stereo-{delay_s}.mcap', PAIRS)
    return run_benchmark(
        RunConfig(
            inputs=[bag],
            backends=['sgbm'],
            out_dir=tmp_path / f'run-{delay_s}-{rate}',
            rate=parse_rate(rate),
            warmup=0,
            report=False,
            sync=parse_sync('exact'),
        ),
        clock=clock,
        backend_factory=lambda _name, _options: cast('Backend', TimedSgbm(clock, delay_s)),
    )


def _expected(shown: dict[int, int | None]) -> dict[str, float | None]:
    matcher = Matcher('sgbm')
    views = [render_stereo((320, 240), i) for i in range(PAIRS)]
    disparities = [matcher.compute(v.left, v.right) for v in views]
    total = DisparityCounts()
    for i, j in shown.items():
        truth = views[i].disparity
        estimate = disparities[j] if j is not None else np.full(truth.shape, np.nan, np.float32)
        total += score_disparity(estimate, truth)
    figures = total.figures()
    return {'epe': figures.epe, 'bad2': figures.bad2, 'density': figures.density}


def _metrics(outcome: RunOutcome) -> dict[str, Any]:
    (row,) = outcome.run.summary_rows
    return dict(row.task_metrics or {})


def test_a_pair_finished_within_the_frame_period_is_scored_against_the_previous_pair(
    tmp_path: Path,
) -> None:
    metrics = _metrics(_run(tmp_path, 0.05))
    expected = _expected({0: None, **{i: i - 1 for i in range(1, PAIRS)}})
    assert metrics['streaming_epe'] == pytest.approx(expected['epe'], abs=1e-9)
    assert metrics['streaming_bad2'] == pytest.approx(expected['bad2'], abs=1e-9)
    assert metrics['streaming_density'] == pytest.approx(expected['density'], abs=1e-9)
    assert metrics['streaming_bad2'] > metrics['bad2']  # the objects moved in between


def test_with_no_delay_the_streaming_figures_are_the_offline_ones(tmp_path: Path) -> None:
    metrics = _metrics(_run(tmp_path, 0.0))
    assert metrics['streaming_epe'] == pytest.approx(metrics['epe'], abs=1e-12)
    assert metrics['streaming_bad2'] == pytest.approx(metrics['bad2'], abs=1e-12)
    assert metrics['streaming_density'] == pytest.approx(metrics['density'], abs=1e-12)


def test_at_rate_max_the_stereo_streaming_figures_are_empty(tmp_path: Path) -> None:
    metrics = _metrics(_run(tmp_path, 0.0, 'max'))
    assert metrics['bad2'] is not None
    assert metrics['streaming_bad2'] is None
