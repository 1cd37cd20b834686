"""``--workers processes``: each per-topic pipeline's backend in a spawned worker process
(``replaybench.replay.workers.ProcessBackend``), frames handed over in shared memory.

The runs replay a real rig bag (``replaybench.fixtures.rig``) through the registered ``hsv``
backend, made in each worker by the registry; the worker's detections must be the ones the
same backend gives in the run's own process, frame by frame.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest
from typer.testing import CliRunner

from replaybench.backends.base import BackendOptions
from replaybench.backends.hsv import HsvBackend
from replaybench.cli import app
from replaybench.errors import BackendError, UsageError
from replaybench.fixtures.rig import write_rig_mcap
from replaybench.replay import Rate
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.replay.sessions import make_backend
from replaybench.replay.workers import ProcessBackend
from replaybench.types import Frame

if TYPE_CHECKING:
    from collections.abc import Iterator

    from replaybench.replay.runner import RunOutcome


@pytest.fixture(scope='module')
def rig(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_rig_mcap(tmp_path_factory.mktemp('rig') / 'rig.mcap', frames=12, cameras=3)


def _run(bag: Path, out: Path, workers: str) -> RunOutcome:
    config = RunConfig(
        inputs=[bag],
        backends=['hsv'],
        out_dir=out,
        rate=Rate('max'),
        pipelines='per-topic',
        workers=workers,
        report=False,
        hash_inputs=False,
    )
    return run_benchmark(config)


def _what_was_found(outcome: RunOutcome) -> list[tuple[object, ...]]:
    return [
        (r.topic, r.seq, r.status, r.warmup, r.dropped, r.detections, r.pipeline)
        for r in outcome.records
    ]


def test_worker_processes_find_what_threads_find_frame_by_frame_and_the_run_says_processes(
    rig: Path, tmp_path: Path
) -> None:
    threads = _run(rig, tmp_path / 'threads', 'threads')
    processes = _run(rig, tmp_path / 'processes', 'processes')
    found = _what_was_found(processes)
    assert found == _what_was_found(threads)
    assert (
        sum(r.detections or 0 for r in processes.records) > 0
    )  # the frames hold blobs: something to agree on
    assert {row[6] for row in found} == {0, 1, 2}
    pipelines = processes.run.settings.pipelines
    assert pipelines is not None
    assert (pipelines.workers, pipelines.pipelines) == ('processes', 3)
    assert threads.run.settings.pipelines is not None
    assert threads.run.settings.pipelines.workers == 'threads'
    scores = [(s.topic, s.map50, s.map50_95) for s in processes.summaries]
    assert scores == [(s.topic, s.map50, s.map50_95) for s in threads.summaries]
    assert any(score[1] is not None for score in scores)


@pytest.fixture
def worker() -> Iterator[ProcessBackend]:
    backend = ProcessBackend('hsv', BackendOptions(), make_backend, HsvBackend())
    backend.open()
    try:
        yield backend
    finally:
        backend.close()


def _frame(image: np.ndarray, encoding: str = 'bgr8') -> Frame:
    return Frame('/cam/image', 3, 10, 20, 'cam', image, encoding, encoding)


def _blobs(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    image = np.full((120, 160, 3), 40, dtype=np.uint8)
    for colour in ((0, 0, 255), (0, 255, 0), (255, 0, 0)):
        x, y = int(rng.integers(0, 120)), int(rng.integers(0, 80))
        image[y : y + 30, x : x + 30] = colour
    return image


def test_a_worker_gives_the_detections_of_the_backend_in_this_process_also_for_a_strided_image(
    worker: ProcessBackend,
) -> None:
    here = HsvBackend()
    here.open()
    for seed in range(3):
        image = _blobs(seed)
        expected = here.detect(_frame(image)).detections
        assert len(expected) == 3
        assert worker.detect(_frame(image)).detections == expected
    wide = np.zeros((120, 320, 3), dtype=np.uint8)
    wide[:, ::2] = _blobs(7)
    strided = wide[:, ::2]  # not contiguous: handed over in the pickle itself
    assert not strided.flags.c_contiguous
    assert worker.detect(_frame(strided)).detections == here.detect(_frame(strided)).detections
    assert worker.info()['worker'] == 'process'
    assert worker.info()['classes'] == here.info()['classes']
    here.close()


def test_what_detect_raises_in_the_worker_is_raised_in_the_run_and_the_worker_goes_on(
    worker: ProcessBackend,
) -> None:
    mono = np.zeros((40, 40), dtype=np.uint8)
    with pytest.raises(BackendError, match=r'expected HxWx3 uint8 for bgr8, got shape \(40, 40\)'):
        worker.detect(_frame(mono))
    assert len(worker.detect(_frame(_blobs(1))).detections) == 3


def test_a_worker_that_dies_is_a_backend_error_naming_its_exit_code(
    worker: ProcessBackend,
) -> None:
    worker.detect(_frame(_blobs(2)))
    process = worker._process
    assert process is not None
    assert process.pid is not None
    os.kill(process.pid, signal.SIGKILL)
    process.join(10)
    with pytest.raises(BackendError, match=r'worker process ended \(exit code -9\)'):
        worker.detect(_frame(_blobs(2)))


def test_closing_a_worker_removes_its_shared_memory_block() -> None:
    backend = ProcessBackend('hsv', BackendOptions(), make_backend, HsvBackend())
    backend.open()
    backend.detect(_frame(_blobs(3)))
    block = backend._block
    assert block is not None
    path = Path('/dev/shm') / block.name.lstrip('/')
    assert path.exists() or not Path('/dev/shm').is_dir()
    backend.close()
    assert not path.exists()
    assert backend._process is None


def test_a_backend_that_cannot_open_in_its_worker_says_why() -> None:
    options = BackendOptions(extra={'kernel': '4'})
    with pytest.raises(Exception, match='kernel') as raised:
        HsvBackend(options)  # refused here as it is in the worker
    backend = ProcessBackend('hsv', options, make_backend, HsvBackend())
    with pytest.raises(type(raised.value), match='kernel'):
        backend.open()
    assert backend._process is None


def test_workers_processes_without_per_topic_pipelines_is_one_line_and_exit_2(
    rig: Path, tmp_path: Path
) -> None:
    args = ['run', str(rig), '--backend', 'hsv', '--workers', 'processes']
    result = CliRunner().invoke(app, [*args, '--out', str(tmp_path / 'run')])
    assert result.exit_code == UsageError.exit_code == 2
    assert result.stderr.strip().splitlines() == [
        (
            'replaybench: error: --workers processes runs the pipelines of --pipelines '
            'per-topic: give both'
        )
    ]
    assert not (tmp_path / 'run').exists()
