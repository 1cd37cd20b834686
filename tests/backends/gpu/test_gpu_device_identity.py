"""GPU figures describe the GPU the backend uses: NVML's device is found by the UUID / PCI bus id
the CUDA driver gives for the backend's device index, not by the index itself (NVML numbers GPUs
in PCI order and ignores ``CUDA_VISIBLE_DEVICES``).

The CUDA driver (``FakeLibcuda``) and NVML (``fake_nvml``) are stood in for at their API.
"""

from __future__ import annotations

import sys
import time

import pytest
from backends.gpu.gpufakes import GPU_A, GPU_B, fake_nvml

from replaybench.backends.gpu._cuda import device_facts, device_identity, normalise_pci_bus_id
from replaybench.replay.resources import ResourceSampler


def _sample(monkeypatch: pytest.MonkeyPatch, nvml: object, index: int) -> dict[str, object]:
    monkeypatch.setitem(sys.modules, 'pynvml', nvml)
    with ResourceSampler(interval_s=0.02, gpu_index=index) as sampler:
        time.sleep(0.05)
    return sampler.summary()


def test_cuda_device_0_behind_cuda_visible_devices_is_sampled_not_nvml_device_0(
    monkeypatch, driver
):
    driver([GPU_A, GPU_B], visible=[1])  # CUDA_VISIBLE_DEVICES=1: CUDA's 0 is the second GPU
    nvml = fake_nvml([GPU_A, GPU_B])
    summary = _sample(monkeypatch, nvml, 0)
    assert summary['gpu_name'] == 'Fake GPU B'
    assert summary['gpu_uuid'] == GPU_B.uuid_text
    assert summary['gpu_pci_bus_id'] == '0000:65:00.0'
    assert summary['gpu_match'] == 'uuid'
    assert summary['gpu_index'] == 0
    assert summary['gpu_mem_mb_peak'] == pytest.approx(5 * 1024)
    assert set(nvml.state['read']) == {'Fake GPU B'}


def test_without_a_uuid_from_nvml_the_pci_bus_id_decides(monkeypatch, driver):
    driver([GPU_A, GPU_B], visible=[1, 0])  # CUDA orders them the other way round
    nvml = fake_nvml([GPU_A, GPU_B])
    del nvml.nvmlDeviceGetUUID
    summary = _sample(monkeypatch, nvml, 1)
    assert summary['gpu_name'] == 'Fake GPU A'
    assert summary['gpu_match'] == 'pci_bus_id'


def test_a_cuda_device_nvml_does_not_list_gives_no_gpu_figures(monkeypatch, driver):
    driver([GPU_A, GPU_B])
    summary = _sample(monkeypatch, fake_nvml([GPU_A]), 1)  # NVML sees only the first
    assert summary['gpu_name'] is None
    assert summary['gpu_mem_mb_peak'] is None


def test_device_facts_carry_the_identity_and_compute_capability(driver):
    driver([GPU_A, GPU_B], visible=[1])
    facts = device_facts(0)
    assert facts.name == 'Fake GPU B'
    assert facts.compute_capability == '9.0'
    assert facts.pci_bus_id == '0000:65:00.0'
    assert facts.uuid == GPU_B.uuid_text
    assert facts.total_memory_bytes == 80 << 30
    assert device_identity(1) is None  # only one GPU is visible


def test_pci_bus_ids_compare_whatever_the_domain_width():
    assert normalise_pci_bus_id('00000000:65:00.0') == '0000:65:00.0'
    assert normalise_pci_bus_id('0000:65:00.0') == '0000:65:00.0'
    assert normalise_pci_bus_id(' 0000:0A:1F.3 ') == '0000:0a:1f.3'
    assert normalise_pci_bus_id('not a bus id') == 'not a bus id'
