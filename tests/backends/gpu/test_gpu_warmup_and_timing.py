"""Warm-up that warms, device time next to host time, and GPU memory given back.

* ``open()`` runs one whole frame: hsv-cuda on an image whose blobs survive its morphology (the
  old 8x8 image was erased by the 5x5 opening, so labelling never ran), cuda one inference;
* stage times: host wall clock after a synchronisation, and the device's own time from timing
  events recorded on the backend's stream, both in frames.csv;
* ``close()`` returns the cached blocks of CuPy's pools and torch's caching allocator.

CuPy is NumPy + SciPy here and its events read a fake device clock (``gpufakes.fake_cupy``);
the CUDA driver is ``FakeLibcuda``; onnxruntime's GPU build and torch's CUDA calls are stood in
for as in the other tests. The replay, frames.csv and the algorithms run for real.
"""

from __future__ import annotations

import csv
import importlib
from typing import Any

import numpy as np
import pytest
from backends.gpu.gpufakes import GPU_A, fake_cupy, fake_gpu_build, torch_on_the_cpu
from backends.gpu.gpuhelpers import FIXTURE_BAGS

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu import _hsv_ops
from replaybench.backends.gpu._cuda import STAGE_EVENTS, EventTimer, StageClock
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.hsv_cuda import (
    HsvCudaBackend,
    detections_from_stats,
    morphology_kernel,
    warmup_image,
)
from replaybench.backends.hsv import HsvBackend
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.results.records import (
    FRAMES_CSV_COLUMNS,
    FrameRecord,
    FramesCsvWriter,
    read_frames_csv,
)

ndi = pytest.importorskip('scipy.ndimage', reason='scipy is not installed')
DEVICE_COLUMNS = (
    'preprocess_device_ms',
    'infer_device_ms',
    'postprocess_device_ms',
    'h2d_device_ms',
    'd2h_device_ms',
)


def _numpy_detections(image: np.ndarray, extra: dict[str, str]) -> list[str]:
    """hsv-cuda's algorithm on NumPy + SciPy: the labels it finds in a BGR image."""
    config = HsvBackend(BackendOptions(extra=extra)).config
    planes = _hsv_ops.to_hsv(np, image, 0, _hsv_ops.hsv_tables())
    params = config.detector
    masks = _hsv_ops.class_masks(
        np,
        ndi,
        planes,
        config.classes,
        morphology_kernel(config),
        params.open_iterations,
        params.close_iterations,
    )
    rows = _hsv_ops.blob_stats(np, ndi, masks, planes[1])
    return [d.label for d in detections_from_stats(rows, config)]


@pytest.mark.parametrize(
    'extra',
    [
        {},
        {'kernel': '9', 'open_iterations': '2', 'close_iterations': '2'},
        {'min_area': '2500'},
        {'kernel': '1'},
    ],
)
def test_the_warmup_image_keeps_one_blob_of_every_class_through_the_morphology(extra):
    config = HsvBackend(BackendOptions(extra=extra)).config
    image = warmup_image(config)
    found = _numpy_detections(image, extra)
    assert sorted(found) == sorted(c.name for c in config.classes)


def test_the_old_tiny_warmup_frame_was_erased_by_the_opening():
    pixels = np.zeros((8, 8, 3), dtype=np.uint8)
    pixels[2:6, 2:6] = (0, 0, 220)
    assert _numpy_detections(pixels, {}) == []


@pytest.fixture
def cupy(monkeypatch, driver):
    driver([GPU_A])
    cupy, cupyx, ndimage = fake_cupy()
    modules = {'cupy': cupy, 'cupyx': cupyx, 'cupyx.scipy.ndimage': ndimage}
    real = importlib.import_module

    def import_module(name: str, package: str | None = None) -> object:
        return modules[name] if name in modules else real(name, package)

    monkeypatch.setattr(importlib, 'import_module', import_module)
    return cupy


def test_hsv_cuda_warms_up_on_every_class_and_gives_its_pools_back(cupy, scene):
    backend = HsvCudaBackend(BackendOptions())
    backend.open()
    info = backend.info()
    result = backend.detect(scene(seed=3).rect('green', 20, 20, 80, 60).frame('bgr8'))
    backend.close()
    assert info['warmup_detections'] == 4
    assert info['warmup_ms'] > 0
    assert [d.label for d in result.detections] == ['green']
    assert [pool.freed for pool in cupy.pools] == [1, 1]


@pytest.mark.usefixtures('cupy')
def test_hsv_cuda_reports_device_time_from_events_on_its_stream(scene):
    backend = HsvCudaBackend(BackendOptions())
    backend.open()
    stages = backend.detect(scene(seed=4).frame('rgb8')).stages
    backend.close()
    quarter_ms = 250_000  # the fake device clock advances 0.25 ms per recorded event
    assert stages.h2d_device_ns == quarter_ms
    assert stages.preprocess_device_ns == quarter_ms
    assert stages.infer_device_ns == quarter_ms
    assert stages.postprocess_device_ns == quarter_ms
    assert stages.d2h_device_ns == quarter_ms
    assert stages.h2d_ns is not None
    assert stages.h2d_ns >= 0


@pytest.mark.usefixtures('cupy')
def test_a_replay_writes_host_and_device_times_to_frames_csv(tmp_path):
    config = RunConfig(
        inputs=[FIXTURE_BAGS / 'rgb8_raw.mcap'],
        backends=['hsv-cuda'],
        out_dir=tmp_path / 'run',
        max_frames=5,
        report=False,
    )
    outcome = run_benchmark(config, backend_factory=lambda name, options: HsvCudaBackend(options))
    assert outcome.run_dir is not None
    with (outcome.run_dir / 'frames.csv').open(newline='', encoding='utf-8') as file:
        rows = list(csv.DictReader(file))
    ok = [r for r in rows if r['status'] == 'ok']
    assert ok
    assert tuple(rows[0])[22:27] == DEVICE_COLUMNS
    for row in ok:
        assert [row[c] for c in DEVICE_COLUMNS] == ['0.2500'] * 5
        assert row['h2d_ms'] != ''
        assert row['infer_ms'] != ''


def test_cuda_runs_one_inference_in_open_and_gives_cached_memory_back(
    monkeypatch, tiny_model, driver
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    fake_torch_cuda = torch_on_the_cpu(monkeypatch, torch)
    seen = fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    backend.open()
    assert seen.runs == 1
    info = backend.info()
    assert info['warmup_ms'] > 0
    backend.close()
    assert fake_torch_cuda.emptied == 1


class _Events:
    """Timing events on a fake device clock: each one stamps the next of the given times."""

    def __init__(self, stamps_ms: list[float]) -> None:
        self.stamps = iter(stamps_ms)
        self.recorded: list[str] = []

    def make(self) -> EventTimer:
        events = [{'t': None} for _ in range(STAGE_EVENTS)]

        def record(event: dict[str, float | None]) -> None:
            event['t'] = next(self.stamps)
            self.recorded.append('record')

        return EventTimer(events, record, lambda a, b: b['t'] - a['t'])


def test_a_stage_clock_records_a_start_and_an_end_event_per_stage_before_it_synchronises():
    # start, end of each stage; the gaps between one stage's end and the next one's start
    # (host work between them) are not in any device time
    fake = _Events([10.0, 10.5, 11.0, 12.5, 13.0, 21.0, 25.0, 25.25, 26.0, 26.75])
    calls = fake.recorded
    clock = StageClock(lambda: calls.append('sync'), fake.make())
    clock.start()
    host = []
    for _ in range(5):
        clock.begin()
        host.append(clock.lap())
    assert calls == ['sync'] + ['record', 'record', 'sync'] * 5
    assert clock.device_laps() == [500_000, 1_500_000, 8_000_000, 250_000, 750_000]
    assert all(h >= 0 for h in host)
    assert StageClock(lambda: None).device_laps() == []


def test_frames_csv_keeps_device_times_and_reads_files_written_before_them(tmp_path):
    times: dict[str, Any] = dict(
        zip(DEVICE_COLUMNS, (0.5, 1.25, 0.125, 0.0625, 0.0375), strict=True)
    )
    record = FrameRecord(
        0, 'cuda', '/cam', 1, 10, 10, 'ok', '', False, False, 0.5, 0.5, 0.51, 0.0, 1.0,
        0.75, 1.5, 0.25, 0.1, 0.05, 3.0, 2, *times.values(),
    )  # fmt: skip
    path = tmp_path / 'frames.csv'
    with FramesCsvWriter(path) as writer:
        writer.write(record)
    assert read_frames_csv(path) == [record]
    text = path.read_text(encoding='utf-8')
    # the device times, then the (empty) tag columns
    assert text.splitlines()[1].endswith(',3.0000,2,0.5000,1.2500,0.1250,0.0625,0.0375,,,,,,,,')

    old = tmp_path / 'old.csv'
    lines = text.splitlines()
    header = ','.join(FRAMES_CSV_COLUMNS[:22])
    old.write_text(f'{header}\r\n{lines[1].rsplit(",", 13)[0]}\r\n', encoding='utf-8')
    no_device: dict[str, Any] = dict.fromkeys(DEVICE_COLUMNS)
    assert read_frames_csv(old) == [record._replace(**no_device)]


def test_the_device_columns_are_the_five_after_detections():
    assert FRAMES_CSV_COLUMNS[22:27] == DEVICE_COLUMNS
    assert FRAMES_CSV_COLUMNS[:22][-2:] == ('latency_ms', 'detections')
