"""A synthetic run folder built with the real writers, for the report tests."""

from __future__ import annotations

import random
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import pytest

from replaybench.report import sample_relpath, write_sample
from replaybench.results import (
    SCHEMA_VERSION,
    FrameRecord,
    FramesCsvWriter,
    summarize,
    summary_json,
)
from replaybench.results.io import from_document, write_run_result
from replaybench.results.model import RunResult
from replaybench.types import Detection

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

HOSTILE = '<script>alert(1)</script>'


def _counts(records: Sequence[FrameRecord]) -> dict[str, int]:
    return {
        'frames': len(records),
        'processed': sum(1 for r in records if r.status == 'ok'),
        'dropped': sum(1 for r in records if r.status == 'dropped'),
        'skipped': sum(1 for r in records if r.status == 'skipped'),
    }


class MakeRun(Protocol):
    def __call__(
        self,
        *,
        frames: int = ...,
        topics: Sequence[str] = ...,
        backends: Sequence[str] = ...,
        status: str = ...,
        samples: bool = ...,
        accuracy: bool = ...,
        truncated: bool = ...,
        skip_every: int = ...,
        drop_every: int = ...,
    ) -> Path: ...


def _records(
    frames: int, topics: Sequence[str], backends: Sequence[str], skip_every: int, drop_every: int
) -> list[FrameRecord]:
    rng = random.Random(7)
    records = []
    for b_index, backend in enumerate(backends):
        base = 2.0 + 3.0 * b_index
        for topic in topics:
            done = 0.0
            for seq in range(frames):
                release = seq / 30.0
                if drop_every and seq % drop_every == drop_every - 1:
                    records.append(
                        FrameRecord(0, backend, topic, seq, seq * 33_000_000, None, 'dropped',
                                    'pushed out of the queue', False, True, release),
                    )  # fmt: skip
                    continue
                if skip_every and seq % skip_every == skip_every - 1:
                    records.append(
                        FrameRecord(0, backend, topic, seq, seq * 33_000_000, None, 'skipped',
                                    'bad jpeg', False, False, release, release, release + 1e-3,
                                    0.0, 1.0),
                    )  # fmt: skip
                    continue
                warm = seq < 3
                latency = base * (1.0 + 0.3 * rng.random()) + (40.0 if warm else 0.0)
                start = max(release, done)
                done = start + latency / 1e3
                records.append(
                    FrameRecord(
                        0, backend, topic, seq, seq * 33_000_000, seq * 33_000_000, 'ok', '',
                        warm, False, release, start, done, (start - release) * 1e3, 0.4,
                        0.2 * latency, 0.5 * latency, 0.1 * latency, None, None,
                        latency + (start - release) * 1e3, rng.randint(0, 3),
                    ),
                )  # fmt: skip
    return records


@pytest.fixture
def make_run(tmp_path: Path) -> MakeRun:
    counter = iter(range(1000))

    def make(
        *,
        frames: int = 200,
        topics: Sequence[str] = ('/cam/front/image_raw',),
        backends: Sequence[str] = ('hsv', 'null'),
        status: str = 'complete',
        samples: bool = False,
        accuracy: bool = False,
        truncated: bool = False,
        skip_every: int = 0,
        drop_every: int = 0,
    ) -> Path:
        run_dir = tmp_path / f'run{next(counter)}'
        run_dir.mkdir()
        records = _records(frames, topics, backends, skip_every, drop_every)
        with FramesCsvWriter(run_dir / 'frames.csv') as writer:
            writer.write_many(records)
        rows = [summary_json(s) for s in summarize(records)]
        if accuracy:
            rows[0]['accuracy'] = {
                'frames': rows[0]['measured'],
                'precision50': 0.875,
                'recall50': 0.625,
                'map50': 0.5432,
                'map50_95': 0.3211,
                'ap50': {'red': 0.5432, HOSTILE: 0.1},
                'ap50_95': {'red': 0.3211, HOSTILE: 0.05},
                'n_gt': 40,
                'n_det': 38,
            }
        sample_paths = []
        if samples:
            image = np.full((360, 640, 3), 90, np.uint8)
            for topic in topics:
                rel = sample_relpath(0, topic)
                dets = {
                    b: (Detection(0, 'red', 0.9, 40.0 + 30 * i, 50.0, 140.0 + 30 * i, 150.0),)
                    for i, b in enumerate(backends)
                }
                write_sample(run_dir / rel, image, dets, f'{topic} #5')
                sample_paths.append(rel)
        skipped = sum(1 for r in records if r.status == 'skipped')
        run: dict[str, Any] = {
            'schema_version': SCHEMA_VERSION,
            'tool': {'name': 'replaybench', 'version': '0.1.0'},
            'status': status,
            'command': ['replaybench', 'run', f'/bags/{HOSTILE}.mcap', '--backend', HOSTILE],
            'started_at': '2025-01-02T03:04:05+00:00',
            'finished_at': '2025-01-02T03:05:05+00:00',
            'wall_s': 60.0,
            'settings': {
                'rate': 'max',
                'queue_depth': 1,
                'warmup': 3,
                'threads': None,
                'max_frames': None,
                'start_s': None,
                'duration_s': None,
                'topics': list(topics),
                'ground_truth_topic': None,
            },
            'inputs': [
                {
                    'index': 0,
                    'path': f'/bags/{HOSTILE}.mcap',
                    'format': 'mcap',
                    'size_bytes': 5_000_000,
                    'sha256': '0123456789abcdef' * 4,
                    'truncated': truncated,
                    'warnings': [f'cut short {HOSTILE}'] if truncated else [],
                    'topics': [
                        {
                            'name': t,
                            'msgtype': 'sensor_msgs/msg/Image',
                            'encoding': 'rgb8',
                            'width': 640,
                            'height': 360,
                            'count': frames,
                            'is_depth': False,
                            'camera_info_topic': None,
                        }
                        for t in topics
                    ],
                },
            ],
            'environment': {
                'cpu': {'model': f'CPU {HOSTILE}', 'logical_cores': 8, 'governor': 'performance'},
                'os': {'system': 'Linux', 'platform': 'Linux-6.8-x86_64'},
                'python': {'version': '3.11.7', 'implementation': 'CPython'},
                'packages': {
                    'replaybench': '0.1.0',
                    'numpy': '2.0',
                    'opencv': {'version': '4.10', 'threads': 8},
                },
                'gpus': [],
            },
            'backends': [
                {
                    'name': b,
                    'label': b,
                    'info': {'note': HOSTILE},
                    'resources': {
                        'summary': {
                            'samples': 0,
                            'interval_s': 0.05,
                            'duration_s': 0.0,
                            'cpu_source': 'process_time',
                        },
                        'series': [],
                    },
                    'record_s': 0.01,
                }
                for b in backends
            ],
            'summary': rows,
            'counts': _counts(records),
            'skipped': {f'bad jpeg {HOSTILE}': skipped} if skipped else {},
            'outputs': {
                'outputs_mcap': 'outputs.mcap',
                'frames_csv': 'frames.csv',
                'summary_csv': 'summary.csv',
                'report': 'report.html',
                'samples': sample_paths,
            },
        }
        write_run_result(run_dir / 'run.json', from_document(RunResult, run))
        return run_dir

    return make
