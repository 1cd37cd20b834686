"""Run folders for the comparison tests, written with the real frames.csv / run.json writers
(a run.json is made a ``RunResult`` first: what it leaves out takes the model's defaults)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from replaybench.results import (
    SCHEMA_VERSION,
    FrameRecord,
    FramesCsvWriter,
    summarize,
    summary_json,
)
from replaybench.results.io import from_document, write_run_result
from replaybench.results.model import RunResult

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from pathlib import Path

    import numpy.typing as npt

TOPIC = '/cam/image_raw'
#: A machine as ``environment()`` describes one (the tests name the host, CPU and GPUs).
MACHINE: dict[str, Any] = {
    'hostname': None,
    'os': {'system': 'Linux', 'platform': 'Linux-6.8-x86_64'},
    'python': {'version': '3.11.7', 'implementation': 'CPython'},
    'packages': {'replaybench': '0.1.0'},
}
#: The accuracy entry of a row before the test's own figures (a figure it leaves out: 0).
UNSCORED: dict[str, Any] = {
    'frames': 0,
    'precision50': 0.0,
    'recall50': 0.0,
    'map50': None,
    'map50_95': None,
    'ap50': {},
    'ap50_95': {},
    'n_gt': 0,
    'n_det': 0,
}
#: A resource summary of a backend that was sampled no time (the tests do not read it).
RESOURCES: dict[str, Any] = {
    'samples': 0,
    'interval_s': 0.05,
    'duration_s': 0.0,
    'cpu_source': 'process_time',
}
SHA = 'ab' * 32
WARMUP = 5


def latencies(
    n: int, median_ms: float, *, seed: int, cv: float = 0.05, rho: float = 0.6
) -> npt.NDArray[np.float64]:
    """Positive, autocorrelated (AR(1) in the log) per-frame latencies around ``median_ms``."""
    rng = np.random.default_rng(seed)
    noise = np.empty(n)
    noise[0] = rng.normal()
    scale = np.sqrt(1.0 - rho * rho)
    for i in range(1, n):
        noise[i] = rho * noise[i - 1] + scale * rng.normal()
    return np.asarray(median_ms * np.exp(cv * noise), dtype=np.float64)


def _records(backend: str, topic: str, measured: npt.ArrayLike) -> list[FrameRecord]:
    """Warm-up frames then the measured ones, processed back to back at --rate max."""
    records = []
    done = 0.0
    given = np.asarray(measured, dtype=np.float64).reshape(-1).tolist()
    values = [given[0] * 3.0] * WARMUP + given
    for seq, latency in enumerate(values):
        release = done
        start = release
        done = start + latency / 1e3
        records.append(
            FrameRecord(
                0, backend, topic, seq, seq * 33_000_000, seq * 33_000_000, 'ok', '',
                seq < WARMUP, False, release, start, done, 0.0, 0.1, None, latency - 0.1,
                None, None, None, latency, 1,
            ),
        )  # fmt: skip
    return records


def write_run(
    path: Path,
    series: Mapping[tuple[str, str], npt.ArrayLike],
    *,
    sha256: str | None = SHA,
    cpu: Mapping[str, Any] | None = None,
    gpus: Sequence[str] = (),
    load_average: Sequence[float] | None = (0.2, 0.2, 0.2),
    info: Mapping[str, Mapping[str, Any]] | None = None,
    accuracy: Mapping[tuple[str, str], Mapping[str, float]] | None = None,
    settings: Mapping[str, Any] | None = None,
    status: str = 'complete',
    bag: str = '/bags/drive.mcap',
) -> Path:
    """A run folder holding ``series[(backend, topic)]`` as the measured latencies (ms)."""
    path.mkdir(parents=True)
    records = [r for (b, t), values in series.items() for r in _records(b, t, values)]
    with FramesCsvWriter(path / 'frames.csv') as writer:
        writer.write_many(records)
    rows = [summary_json(s) for s in summarize(records)]
    for row in rows:
        acc = (accuracy or {}).get((row['backend'], row['topic']))
        if acc is not None:
            row['accuracy'] = {**UNSCORED, 'frames': row['measured'], **acc}
            row.update(acc)
    backends = list(dict.fromkeys(b for b, _ in series))
    run: dict[str, Any] = {
        'schema_version': SCHEMA_VERSION,
        'tool': {'name': 'replaybench', 'version': '0.1.0'},
        'status': status,
        'command': ['replaybench', 'run', bag],
        'started_at': '2025-01-02T03:04:05+00:00',
        'finished_at': '2025-01-02T03:05:05+00:00',
        'wall_s': 60.0,
        'settings': {
            'rate': 'max',
            'queue_depth': 1,
            'warmup': WARMUP,
            'threads': None,
            'max_frames': None,
            'start_s': None,
            'duration_s': None,
            **(settings or {}),
        },
        'inputs': [
            {
                'index': 0,
                'path': bag,
                'format': 'mcap',
                'size_bytes': 1000,
                'sha256': sha256,
                'truncated': False,
                'warnings': [],
                'topics': [
                    {'name': t, 'msgtype': 'sensor_msgs/msg/Image'}
                    for t in dict.fromkeys(t for _, t in series)
                ],
            },
        ],
        'environment': {
            **MACHINE,
            'cpu': {
                'model': 'Intel(R) Xeon(R) Gold 6130 CPU @ 2.10GHz',
                'logical_cores': 8,
                'usable_cores': 8,
                'governor': 'performance',
                **(cpu or {}),
            },
            'load_average': list(load_average) if load_average is not None else None,
            'gpus': [{'name': g, 'driver_version': '550', 'memory_total': '1 MiB'} for g in gpus],
        },
        'backends': [
            {
                'name': b,
                'label': b,
                'info': dict((info or {}).get(b, {})),
                'resources': {'summary': RESOURCES, 'series': []},
                'record_s': 0.01,
            }
            for b in backends
        ],
        'summary': rows,
        'counts': {
            'frames': len(records),
            'processed': sum(1 for r in records if r.status == 'ok'),
            'dropped': sum(1 for r in records if r.status == 'dropped'),
            'skipped': sum(1 for r in records if r.status == 'skipped'),
        },
        'outputs': {'frames_csv': 'frames.csv'},
    }
    write_run_result(path / 'run.json', from_document(RunResult, run))
    return path
