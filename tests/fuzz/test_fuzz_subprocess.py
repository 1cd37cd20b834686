"""A handful of hostile inputs replayed by the real ``python -m replaybench`` process: no
traceback on stderr, exit code 0 or 2, a hard time limit, and peak memory (the child's own
``ru_maxrss``) within 200 MB of a clean replay."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from typing import TYPE_CHECKING, NamedTuple

import pytest
from fuzz.fuzzkit import (
    bag_chunk_boundaries,
    check_run_folder,
    drop_records,
    fixture_bytes,
    mcap_image_fields,
    mcap_records,
    patch_sof,
    put_uint,
    rewrite_mcap,
    write_case,
)

if TYPE_CHECKING:
    from pathlib import Path

TIMEOUT_S = 60
MEMORY_GROWTH = 200 << 20


class Child(NamedTuple):
    code: int
    stderr: str
    maxrss: int  # bytes
    elapsed: float


def run_child(inp: Path, out: Path, workdir: Path) -> Child:
    """``python -m replaybench run`` with a timeout; its own peak RSS from ``wait4``."""
    args = [sys.executable, '-m', 'replaybench', 'run', str(inp), '--out', str(out)]
    args += ['--backend', 'hsv', '--backend', 'null']
    err_path = workdir / f'{out.name}.stderr'
    t0 = time.monotonic()
    with err_path.open('wb') as err:
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=err, cwd=workdir)
        try:
            while True:
                pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
                if pid:
                    break
                if time.monotonic() - t0 > TIMEOUT_S:
                    proc.kill()
                    os.wait4(proc.pid, 0)
                    pytest.fail(f'replaybench ran longer than {TIMEOUT_S} s on {inp}')
                time.sleep(0.01)
        finally:
            proc.returncode = proc.returncode if proc.returncode is not None else -1
    code = os.waitstatus_to_exitcode(status)
    proc.returncode = code
    return Child(
        code, err_path.read_text(errors='replace'), usage.ru_maxrss * 1024, time.monotonic() - t0
    )


@pytest.fixture(scope='module')
def baseline_rss(tmp_path_factory) -> int:
    """Peak RSS of a clean replay of the largest fixture."""
    work = tmp_path_factory.mktemp('baseline')
    case = write_case(work, {'rgb8_raw.mcap': fixture_bytes('rgb8_raw.mcap')})
    child = run_child(case / 'rgb8_raw.mcap', work / 'out', work)
    assert child.code == 0, child.stderr
    return child.maxrss


def huge_raw_image() -> tuple[str, bytes]:
    data = fixture_bytes('rgb8_raw.mcap')
    for fields in mcap_image_fields('rgb8_raw.mcap'):
        data = put_uint(data, fields['width'].pos, 4, 100_000)
        data = put_uint(data, fields['height'].pos, 4, 100_000)
    return 'rgb8_raw.mcap', data


def huge_jpeg() -> tuple[str, bytes]:
    def message(topic: str, payload: bytes) -> bytes:
        if not topic.endswith('/compressed'):
            return payload
        start = payload.index(b'\xff\xd8\xff')
        return payload[:start] + patch_sof(payload[start:], 30_000, 8_000)

    return 'jpeg.mcap', rewrite_mcap(
        fixture_bytes('jpeg.mcap'), message=message, compression='zstd'
    )


def bag_cut_mid_chunk() -> tuple[str, bytes]:
    cut = bag_chunk_boundaries('rgb8.bag')[0] + 500_000
    return 'rgb8.bag', fixture_bytes('rgb8.bag')[:cut]


def huge_chunk_length() -> tuple[str, bytes]:
    chunk = next(r for r in mcap_records('two_camera.mcap') if r.op == 0x06)
    return 'two_camera.mcap', put_uint(
        fixture_bytes('two_camera.mcap'), chunk.start + 1, 8, 2**64 - 1
    )


def huge_uncompressed_size() -> tuple[str, bytes]:
    chunk = next(r for r in mcap_records('jpeg.mcap') if r.op == 0x06)
    field = chunk.fields['uncompressed_size']
    return 'jpeg.mcap', put_uint(fixture_bytes('jpeg.mcap'), field.pos, 8, 2**62)


def schema_dropped() -> tuple[str, bytes]:
    return 'rgb8_raw.mcap', drop_records('rgb8_raw.mcap', 0x03, None)


def db3_header_smashed() -> tuple[str, bytes]:
    data = fixture_bytes('bgr8_rosbag2/bgr8_rosbag2.db3')
    return 'bgr8_rosbag2.db3', data[:4096] + b'\xff' * 4096 + data[8192:]


CASES = {
    'raw-image-100000x100000': huge_raw_image,
    'jpeg-claiming-30000x8000': huge_jpeg,
    'bag-cut-mid-chunk': bag_cut_mid_chunk,
    'chunk-length-u64-max': huge_chunk_length,
    'chunk-uncompressed-size-2^62': huge_uncompressed_size,
    'schema-records-dropped': schema_dropped,
    'db3-page-overwritten': db3_header_smashed,
}


@pytest.mark.parametrize('name', list(CASES))
def test_hostile_input_in_a_real_process_exits_cleanly_in_bounded_memory(
    tmp_path, baseline_rss, name
):
    file_name, data = CASES[name]()
    case = write_case(tmp_path, {file_name: data})
    out = tmp_path / 'run'
    child = run_child(case / file_name, out, tmp_path)
    assert 'Traceback' not in child.stderr, child.stderr
    assert child.code in (0, 2), child.stderr
    growth = child.maxrss - baseline_rss
    assert growth < MEMORY_GROWTH, (
        f'peak RSS {child.maxrss >> 20} MiB, clean run {baseline_rss >> 20} MiB'
    )
    check_run_folder(child.code, out)
