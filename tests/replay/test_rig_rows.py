"""The rig's rows on a real rig bag (``replaybench.fixtures.rig``, four cameras at 30 Hz, the last
starting 2 frames late), on a virtual clock: summary.csv's ``rig`` row per backend, run.json's
``rig`` section, frames.csv's ``pipeline`` column, and compare's ``rig_p99_ms`` and
``rig_drop_rate``.

The backend waits 20 ms a frame on the virtual clock (no CPU), and 40 ms on one camera: with
one instance per camera that camera alone cannot keep up with 30 Hz, so it drops frames and has
the highest p99 latency; shared, one instance serves at most 50 of the 120 frames a second.
"""

from __future__ import annotations

import csv
import json
from collections import Counter
from typing import TYPE_CHECKING, Any, ClassVar

import pytest

from replaybench.backends.base import Availability
from replaybench.comparison import compare_runs, evaluate_gate
from replaybench.fixtures.rig import LATE_FRAMES, rig_topics, write_rig_mcap
from replaybench.replay import Rate, ThreadVirtualClock
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.results.folder import load_run
from replaybench.types import BackendResult, Frame, StageTimes

if TYPE_CHECKING:
    from pathlib import Path

FRAMES = 90  # 3 s at 30 Hz
CAMERAS = [image for image, _, _ in rig_topics(4)]
SLOW = CAMERAS[1]
SERVICE_S = {camera: 0.040 if camera == SLOW else 0.020 for camera in CAMERAS}


class Waiting:
    """Waits ``SERVICE_S[topic]`` per frame on the virtual clock."""

    name: ClassVar[str] = 'waiting'
    description: ClassVar[str] = 'waits 20 ms a frame, 40 ms on one camera'

    def __init__(self, clock: ThreadVirtualClock) -> None:
        self.clock = clock

    @classmethod
    def available(cls) -> Availability:
        return Availability(True)

    def open(self) -> None:
        pass

    def detect(self, frame: Frame) -> BackendResult:
        wait = SERVICE_S[frame.topic]
        self.clock.advance(wait)
        return BackendResult((), StageTimes(infer_ns=int(wait * 1e9)))

    def info(self) -> dict[str, Any]:
        return {}

    def close(self) -> None:
        pass


@pytest.fixture(scope='module')
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_rig_mcap(tmp_path_factory.mktemp('rig') / 'rig.mcap', FRAMES, (64, 48), 4)


def _run(bag: Path, out: Path | None, pipelines: str, *, backends: int = 1) -> Any:
    clock = ThreadVirtualClock()
    config = RunConfig(
        inputs=[bag],
        backends=['waiting', 'other'][:backends],
        out_dir=out,
        rate=Rate('recorded'),
        pipelines=pipelines,
        threads=1,
        report=False,
        hash_inputs=False,
    )
    return run_benchmark(config, clock=clock, backend_factory=lambda _n, _o: Waiting(clock))


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as file:
        return list(csv.DictReader(file))


def test_a_per_topic_run_has_one_rig_row_holding_the_sums_and_names_the_worst_camera(
    rig: Path, tmp_path: Path
) -> None:
    outcome = _run(rig, tmp_path / 'run', 'per-topic')
    records = outcome.records
    frames = Counter(r.topic for r in records)
    dropped = Counter(r.topic for r in records if r.dropped)
    assert sum(frames.values()) == 4 * FRAMES - LATE_FRAMES
    # only the 40 ms camera falls behind 30 Hz
    assert set(dropped) == {SLOW}
    assert dropped[SLOW] > 0

    rows = _csv(tmp_path / 'run' / 'summary.csv')
    assert [r['topic'] for r in rows] == [*CAMERAS, 'rig']
    rig_row = rows[-1]
    assert int(rig_row['frames']) == sum(int(r['frames']) for r in rows[:-1]) == 358
    assert int(rig_row['dropped']) == sum(int(r['dropped']) for r in rows[:-1]) == dropped[SLOW]
    for key in ('processed', 'measured', 'warmup', 'skipped'):
        assert int(rig_row[key]) == sum(int(r[key]) for r in rows[:-1])
    # latency over every camera's measured frames: 20 ms on three cameras, 40 ms and more on one
    measured = [r for r in records if r.status == 'ok' and not r.warmup]
    assert float(rig_row['latency_ms_min']) == pytest.approx(20.0)
    assert float(rig_row['latency_ms_max']) == pytest.approx(max(r.latency_ms for r in measured))
    assert float(rig_row['latency_ms_p99']) >= 40.0
    assert rig_row['jitter_ms'] == ''
    # throughput: every camera's measured frames over the union of their windows
    ends = max(r.done_s for r in measured)
    starts = []
    for camera in CAMERAS:
        mine = [r for r in records if r.topic == camera and r.status == 'ok']
        warm = [r for r in mine if r.warmup]
        starts.append(warm[-1].done_s if warm else mine[0].start_s)
    assert float(rig_row['throughput_fps']) == pytest.approx(
        len(measured) / (ends - min(starts)), rel=1e-3
    )

    run = json.loads((tmp_path / 'run' / 'run.json').read_text(encoding='utf-8'))
    (section,) = run['rig']['backends']
    assert run['rig']['mode'] == 'per-topic'
    assert run['rig']['threads_per_pipeline'] == 1
    assert section['cameras'] == [{'topic': c, 'pipeline': i} for i, c in enumerate(CAMERAS)]
    assert section['pipelines'] == 4
    assert (section['frames'], section['dropped']) == (358, dropped[SLOW])
    assert section['drop_rate'] == pytest.approx(dropped[SLOW] / 358)
    assert section['worst_p99']['topic'] == SLOW
    assert section['worst_p99']['value'] >= 40.0
    assert section['worst_drop_rate'] == {
        'topic': SLOW,
        'value': pytest.approx(dropped[SLOW] / frames[SLOW]),
    }
    # frames.csv: each camera's frames served by its own pipeline, the column before the
    # output age (docs/streaming.md)
    framed = _csv(tmp_path / 'run' / 'frames.csv')
    assert list(framed[0])[-2:] == ['pipeline', 'output_age_ms']
    assert {(r['topic'], r['pipeline']) for r in framed} == {
        (c, str(i)) for i, c in enumerate(CAMERAS)
    }
    # the API tables hold the rig row too, and the run's counts are not doubled
    loaded = load_run(tmp_path / 'run')
    assert list(loaded.run.summary['topic']) == [*CAMERAS, 'rig']
    assert loaded.run.counts is not None
    assert loaded.run.counts.frames == 358
    assert loaded.run.rig == outcome.run.rig


def test_a_shared_run_has_a_rig_row_too_served_by_one_pipeline(rig: Path, tmp_path: Path) -> None:
    outcome = _run(rig, tmp_path / 'run', 'shared', backends=2)
    rows = [(r.backend, r.topic) for r in outcome.summaries]
    assert rows == [
        *(('waiting', c) for c in CAMERAS),
        ('waiting', 'rig'),
        *(('other', c) for c in CAMERAS),
        ('other', 'rig'),
    ]
    dropped = Counter((r.backend, r.topic) for r in outcome.records if r.dropped)
    frames = Counter((r.backend, r.topic) for r in outcome.records)
    assert outcome.run.rig is not None
    assert outcome.run.rig.mode == 'shared'
    for backend, section in zip(('waiting', 'other'), outcome.run.rig.backends, strict=True):
        (row,) = [s for s in outcome.summaries if (s.backend, s.topic) == (backend, 'rig')]
        assert row.frames == 358
        assert row.dropped == sum(n for (b, _), n in dropped.items() if b == backend)
        # one instance serves at most 50 of the 120 frames a second
        assert row.dropped / row.frames >= 0.55
        assert section.pipelines == 1
        assert {c.pipeline for c in section.cameras} == {0}
        # the camera that lost the largest share of its frames, the first of equals
        rates = {c: dropped[backend, c] / frames[backend, c] for c in CAMERAS}
        worst = next(c for c in CAMERAS if rates[c] == max(rates.values()))
        assert section.worst_drop_rate is not None
        assert section.worst_drop_rate.topic == worst
        assert section.worst_drop_rate.value == pytest.approx(rates[worst])
        assert row.metric('rig_drop_rate') == pytest.approx(row.dropped / row.frames)
    # a camera's row has no rig metric
    assert all(s.metric('rig_p99_ms') is None for s in outcome.summaries if s.topic != 'rig')
    assert {r.pipeline for r in outcome.records} == {0}


def test_a_run_of_one_camera_has_no_rig_row_and_no_rig_section(tmp_path: Path) -> None:
    bag = write_rig_mcap(tmp_path / 'one.mcap', 12, (64, 48), 1)
    outcome = _run(bag, tmp_path / 'run', 'shared')
    assert [s.topic for s in outcome.summaries] == [CAMERAS[0]]
    assert outcome.run.rig is None
    assert 'rig' not in json.loads((tmp_path / 'run' / 'run.json').read_text(encoding='utf-8'))


def test_compare_gates_rig_metrics_on_rig_rows_and_the_others_on_camera_rows(
    rig: Path, tmp_path: Path
) -> None:
    _run(rig, tmp_path / 'shared', 'shared')
    _run(rig, tmp_path / 'per-topic', 'per-topic')
    # per-topic against shared: the rig's drops fall from over half to the slow camera's few
    comparison = compare_runs([tmp_path / 'shared', tmp_path / 'per-topic'])
    rig_rows = [r for r in comparison.rows if r.topic == 'rig']
    assert [(r.run, r.role) for r in rig_rows] == [(0, 'baseline'), (1, 'candidate')]
    drop = rig_rows[1].metrics['rig_drop_rate']
    assert drop.value is not None
    assert drop.baseline is not None
    assert drop.baseline >= 0.55
    assert drop.diff == pytest.approx(drop.value - drop.baseline)
    assert all(r.metrics['rig_p99_ms'].value is None for r in comparison.rows if r.topic != 'rig')
    results = evaluate_gate(
        comparison, ['rig_drop_rate > +0.01', 'rig_p99_ms > +10%', 'p99_ms > +10%']
    )
    judged = Counter((r.condition, r.topic) for r in results)
    assert judged == {
        ('rig_drop_rate > +0.01', 'rig'): 1,
        ('rig_p99_ms > +10%', 'rig'): 1,
        **{('p99_ms > +10%', c): 1 for c in CAMERAS},
    }
    assert [r.verdict for r in results if r.condition == 'rig_drop_rate > +0.01'] == ['passed']
    # the other way round the drop rate rises past the threshold
    back = compare_runs([tmp_path / 'per-topic', tmp_path / 'shared'])
    (failed,) = evaluate_gate(back, ['rig_drop_rate > +0.01'])
    assert failed.verdict == 'failed'
    assert 'rig drop rate' in failed.explanation
