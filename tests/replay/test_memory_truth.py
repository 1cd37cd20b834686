"""Memory figures tell what a backend allocated, not how big the memory-mapped input is.

The input bag is memory-mapped; every page of it that the replay reads stays resident until the
kernel needs it back, so the RSS of a run over a 600 MiB bag is over 600 MiB whatever the backend
does. The first memory figure (terminal, summary.csv, run.json, report) is the private
(anonymous) memory instead, RssAnon; the mapped pages are reported apart as ``mapped_mb_peak``.
"""

from __future__ import annotations

import csv
import json
import mmap
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from bagtools import image_msg, write_mcap

from replaybench.replay.resources import ResourceSampler

REPO = Path(__file__).resolve().parents[2]
PROC = Path('/proc')
pytestmark = pytest.mark.skipif(not (PROC / 'self' / 'statm').exists(), reason='needs /proc')

BIG_FRAMES = 230  # 1280x720 rgb8: 2.6 MiB a frame, a 600 MiB bag
BIG_SIZE = (1280, 720)


@pytest.fixture(scope='module')
def big_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An uncompressed MCAP of about 600 MiB (written in a few seconds)."""
    path = tmp_path_factory.mktemp('big') / 'big.mcap'
    width, height = BIG_SIZE
    base = np.random.default_rng(0).integers(0, 255, size=(height, width, 3), dtype=np.uint8)

    def messages():
        for i in range(BIG_FRAMES):
            stamp = 10**9 + i * 33_000_000
            pixels = np.roll(base, i, axis=1)
            yield '/camera/image_raw', stamp, image_msg(stamp, pixels), 'sensor_msgs/msg/Image'

    write_mcap(path, messages(), chunk_size=4 << 20)
    return path


def _status_kib(pid: int, field: str) -> int | None:
    try:
        text = (PROC / str(pid) / 'status').read_text()
    except OSError:
        return None
    found = re.search(rf'^{field}:\s+(\d+) kB', text, re.MULTILINE)
    return int(found.group(1)) if found else None


def test_mapping_a_file_raises_mapped_memory_not_private_memory(tmp_path: Path) -> None:
    data = tmp_path / 'input.bin'
    data.write_bytes(np.random.default_rng(1).bytes(160 << 20))
    with (
        data.open('rb') as handle,
        ResourceSampler(interval_s=0.02) as sampler,
        mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) as mapped,
    ):
        time.sleep(0.05)
        total = 0
        for offset in range(0, len(mapped), 4096):  # touch every page: all resident
            total += mapped[offset]
        time.sleep(0.1)
    summary = sampler.summary()
    first = sampler.series()[0]
    assert summary['mapped_mb_peak'] - first['mapped_mb'] >= 140
    assert summary['private_mb_peak'] - first['private_mb'] < 40
    assert summary['rss_mb_peak'] >= summary['private_mb_peak'] + 140


def test_allocating_raises_private_memory() -> None:
    with ResourceSampler(interval_s=0.02) as sampler:
        time.sleep(0.05)
        block = np.ones(200 * 1_000_000, dtype=np.uint8)  # written, so resident
        time.sleep(0.15)
        del block
    summary = sampler.summary()
    series = sampler.series()
    assert summary['private_mb_peak'] - series[0]['private_mb'] >= 150
    private = [mb for mb in (p['private_mb'] for p in series) if mb is not None]
    assert len(private) == len(series)
    assert summary['private_mb_peak'] == pytest.approx(max(private))
    assert summary['private_mb_mean'] <= summary['private_mb_peak']
    assert summary['mapped_mb_peak'] < summary['private_mb_peak']


def test_a_600_mib_bag_shows_its_private_memory_first_as_rssanon_seen_from_outside(
    big_bag: Path, tmp_path: Path
) -> None:
    out = tmp_path / 'run'
    bag_mib = big_bag.stat().st_size / 2**20
    command = [sys.executable, '-m', 'replaybench', 'run', str(big_bag), '-b', 'hsv']
    proc = subprocess.Popen(
        [*command, '--out', str(out)], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    outside: list[int] = []  # RssAnon of the process, read from /proc/PID/status by this one
    while proc.poll() is None:
        anon = _status_kib(proc.pid, 'RssAnon')
        if anon is not None:
            outside.append(anon)
        time.sleep(0.01)
    stdout, stderr = proc.communicate()
    assert proc.returncode == 0, stderr.decode()
    run = json.loads((out / 'run.json').read_text())
    summary = run['backends'][0]['resources']['summary']
    memory = [k for k in summary if k.endswith(('_mb_peak', '_mb_mean')) and 'gpu' not in k]
    assert memory[0] == 'private_mb_peak'

    private = summary['private_mb_peak']
    assert private < 300
    # what the kernel says of the same process, sampled from outside over the whole command
    # (start-up and report included, so it may be a little higher, never lower by much)
    assert outside, 'the run ended before it could be sampled'
    assert private == pytest.approx(max(outside) / 1024, abs=25)
    # the input's pages are there, under their own name, and in the plain RSS
    assert summary['mapped_mb_peak'] >= 0.8 * bag_mib
    assert summary['rss_mb_peak'] >= private + 0.8 * bag_mib

    with (out / 'summary.csv').open(newline='') as f:
        rows = list(csv.DictReader(f))
        header = list(rows[0])
    memory_columns = [c for c in header if c.endswith('_mb_peak') and 'gpu' not in c]
    assert memory_columns == ['private_mb_peak', 'mapped_mb_peak', 'rss_mb_peak']
    assert float(rows[0]['private_mb_peak']) == pytest.approx(private, abs=1e-3)

    lines = stdout.decode().splitlines()
    head = lines[0].split()
    assert head[-2:] == ['private', 'MiB']
    assert lines[1].split()[-1] == f'{private:.0f}'

    html = (out / 'report.html').read_text()
    table = html[html.index('id="resources"') :]
    table = table[: table.index('</table>')]
    assert table.index('private peak MiB') < table.index('mapped input') < len(table)
    assert 'RSS' not in table
    assert f'>{private:.1f}<' in table
