"""Device times span the stage's own GPU work: a start event just before the stage's first GPU
call and an end event after its last, not the gap since the previous stage's synchronisation.

Every stage boundary synchronises the stream, so an event recorded at the boundary completes at
once on the idle stream: an interval between consecutive boundary events counts the host work
that came before the next stage's first GPU call (the copy into pinned memory before an upload).
Here the timing events stamp the host's clock when recorded, as a start event does on an idle
stream, and that host work is made long (a 30 ms staging copy): the device span must not hold
it, the host lap must. Events and streams are stood in for (``gpufakes``); the pipelines run.
"""

from __future__ import annotations

import importlib
import time
from typing import Any

import pytest
from backends.gpu.gpufakes import GPU_A, fake_cupy, fake_gpu_build, torch_on_the_cpu

from replaybench.backends.base import BackendOptions
from replaybench.backends.gpu._cuda import STAGE_EVENTS, EventTimer, StageClock
from replaybench.backends.gpu.cuda import CudaBackend
from replaybench.backends.gpu.hsv_cuda import HsvCudaBackend

STAGING_S = 0.03
STAGING_NS = int(STAGING_S * 1e9)


def _host_clock_events(slots: int = STAGE_EVENTS, log: list[str] | None = None) -> EventTimer:
    """Events that complete when recorded (an idle stream), stamped with the host's clock;
    ``log`` gets ``event N`` for each one recorded."""
    events: list[dict[str, int]] = [{'t': 0, 'n': n} for n in range(slots)]

    def record(event: dict[str, int]) -> None:
        event['t'] = time.perf_counter_ns()
        if log is not None:
            log.append(f'event {event["n"]}')

    return EventTimer(events, record, lambda a, b: (b['t'] - a['t']) / 1e6)


def test_a_stage_spans_from_its_begin_to_its_lap_and_the_host_lap_from_the_previous_lap():
    recorded: list[str] = []
    timer = _host_clock_events(log=recorded)
    clock = StageClock(lambda: recorded.append('sync'), timer)
    clock.start()
    time.sleep(STAGING_S)  # host work before the stage's first GPU call
    clock.begin()
    host = clock.lap()
    clock.begin()
    clock.lap()
    assert recorded == ['sync', 'event 0', 'event 1', 'sync', 'event 2', 'event 3', 'sync']
    device = clock.device_laps()
    assert len(device) == 2
    assert host >= STAGING_NS
    assert device[0] is not None
    assert device[0] < STAGING_NS // 3


def test_a_stage_without_begin_or_begun_twice_is_a_programming_error():
    clock = StageClock(lambda: None, _host_clock_events())
    clock.start()
    with pytest.raises(RuntimeError, match='ended without begin'):
        clock.lap()
    clock.begin()
    with pytest.raises(RuntimeError, match='has begun already'):
        clock.begin()


def test_a_stage_clock_needs_a_start_and_an_end_event_per_stage():
    assert STAGE_EVENTS == 10
    with pytest.raises(ValueError, match='needs 10 events, not 6'):
        StageClock(lambda: None, _host_clock_events(6))


@pytest.fixture
def cupy(monkeypatch, driver):
    driver([GPU_A])
    cupy, cupyx, ndimage = fake_cupy()
    modules = {'cupy': cupy, 'cupyx': cupyx, 'cupyx.scipy.ndimage': ndimage}
    real = importlib.import_module

    def import_module(name: str, package: str | None = None) -> object:
        return modules[name] if name in modules else real(name, package)

    monkeypatch.setattr(importlib, 'import_module', import_module)
    cupy.cuda.Event = HostClockEvent
    cupy.cuda.get_elapsed_time = lambda a, b: (b.t - a.t) / 1e6
    return cupy


class HostClockEvent:
    """A CuPy event that completes when recorded (an idle stream), stamped with the host clock."""

    t = 0

    def record(self, stream: Any = None) -> None:
        self.t = time.perf_counter_ns()


def _slow(stage: Any) -> Any:
    def staged(*args: Any) -> Any:
        time.sleep(STAGING_S)
        return stage(*args)

    return staged


@pytest.mark.usefixtures('cupy')
def test_hsv_cuda_h2d_device_time_leaves_out_the_copy_into_pinned_memory(monkeypatch, scene):
    backend = HsvCudaBackend(BackendOptions())
    backend.open()
    monkeypatch.setattr(backend, '_stage', _slow(backend._stage))
    stages = backend.detect(scene(seed=5).rect('green', 10, 10, 60, 40).frame('bgr8')).stages
    backend.close()
    assert stages.h2d_ns is not None
    assert stages.h2d_ns >= STAGING_NS
    assert stages.h2d_device_ns is not None
    assert stages.h2d_device_ns < STAGING_NS // 3


def test_cuda_h2d_device_time_leaves_out_the_copy_into_pinned_memory(
    monkeypatch, tiny_model, driver, scene
):
    torch = pytest.importorskip('torch')
    driver([GPU_A])
    torch_on_the_cpu(monkeypatch, torch)
    fake_gpu_build(monkeypatch, ['CUDAExecutionProvider', 'CPUExecutionProvider'])
    backend = CudaBackend(BackendOptions(model=tiny_model, engine='ort'))
    backend.open()
    backend._events = _host_clock_events()
    pipeline = backend._pipeline
    assert pipeline is not None
    monkeypatch.setattr(pipeline, 'stage', _slow(pipeline.stage))
    stages = backend.detect(scene(seed=6).frame('bgr8')).stages
    backend.close()
    assert stages.h2d_ns is not None
    assert stages.h2d_ns >= STAGING_NS
    assert stages.h2d_device_ns is not None
    assert stages.h2d_device_ns < STAGING_NS // 3
    # every stage has its own span, each within its host lap
    for device, host in (
        (stages.preprocess_device_ns, stages.preprocess_ns),
        (stages.infer_device_ns, stages.infer_ns),
        (stages.d2h_device_ns, stages.d2h_ns),
    ):
        assert device is not None
        assert host is not None
        assert 0 <= device <= host
