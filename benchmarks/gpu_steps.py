"""The GPU check's own steps (benchmarks/gpu_check.py): its inputs and its summary.

``python -m benchmarks.gpu_steps inputs DIR --frames N --size WxH`` writes ``rgb8_raw.mcap`` and
``jpeg.mcap`` with the project's fixture writer (``replaybench.fixtures.writer.write_mcap``: the
same scene, ground truth and camera as ``replaybench fixtures``, only those two bags), and
``stereo.mcap``, the stereo fixture (``replaybench.fixtures.stereo.write_stereo_mcap``: rectified
320x240 pairs with exact ground-truth disparity, at most ``STEREO_PAIRS`` of them), and
``rig.mcap``, the rig fixture (``replaybench.fixtures.rig.write_rig_mcap``: ``RIG_CAMERAS``
JPEG cameras at 30 Hz, 640x480 or the given size where smaller, at most ``RIG_FRAMES`` frames
a camera), and ``seg.mcap`` (``write_mcap`` with ``masks``: JPEG frames with truth label masks,
320x240, at most ``SEG_FRAMES``).

``python -m benchmarks.gpu_steps summary WORK OUT`` reads the run folders under ``WORK/runs``
and the peak folder ``WORK/peak`` and writes ``OUT/summary.json`` and ``OUT/summary.md``: per run
and backend the throughput, latency percentiles, host stage means, the stereo figures (summary.csv),
device stage means and host minus device per frame (frames.csv, measured frames only), the engine
facts of run.json, the agreement between the run's backends (detections, and disparities:
run.json ``stereo_agreement``), and the peak rate. Only figures read from
those files; a missing file or column is reported as missing, never filled in.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
import sys
from pathlib import Path
from typing import Any

__all__ = ['main', 'summarise', 'write_inputs']

STAGES = ('h2d', 'preprocess', 'infer', 'postprocess', 'd2h')
#: the stereo bag's pairs (320x240, the bundled stereo model's input size)
STEREO_PAIRS = 60
#: the rig bag: four cameras sharing one GPU, three seconds of them
RIG_CAMERAS = 4
RIG_FRAMES = 90
RIG_SIZE = (640, 480)
#: the segmentation bag: JPEG frames with truth masks at the bundled blobs_seg model's size
SEG_FRAMES = 60
SEG_SIZE = (320, 240)
#: run.json backends[].info keys copied into the summary (docs/gpu.md, run.json info)
INFO_KEYS = (
    'engine',
    'engine_choice',
    'providers',
    'ep_nodes',
    'precision',
    'tf32',
    'device_name',
    'compute_capability',
    'driver',
    'cuda_version',
    'warmup_ms',
    'syncs_per_forward',
    'cuda_graph',
    'warmup_detections',
)
SUMMARY_KEYS = (
    'frames',
    'measured',
    'dropped',
    'throughput_fps',
    'latency_ms_p50',
    'latency_ms_p95',
    'latency_ms_p99',
    'detections_per_frame',
    'epe',
    'bad2',
    'density',
)
#: run.json stereo_agreement: the second backend's disparities against the first's
STEREO_AGREEMENT_KEYS = (
    'backend_a',
    'backend_b',
    'topic',
    'frames',
    'epe',
    'bad1',
    'bad2',
    'bad3',
    'density',
)
RESOURCE_KEYS = ('gpu_mem_mb_start', 'gpu_mem_mb_peak', 'gpu_mem_mb_pass_peak', 'gpu_match')
AGREEMENT_KEYS = (
    'backend_a',
    'backend_b',
    'topic',
    'frames',
    'n_a',
    'n_b',
    'matched',
    'matched_frac_a',
    'matched_frac_b',
    'mean_iou',
    'mean_abs_score_diff',
)


def write_inputs(out: Path, frames: int, size: tuple[int, int]) -> list[Path]:
    """Write the check's bags (raw rgb8, zstd JPEG, the stereo pairs, a four-camera JPEG rig
    and JPEG frames with truth label masks) into ``out``, one process each (the first two
    render the same frames; 300 at 1080p take tens of seconds); return their paths."""
    from concurrent.futures import ProcessPoolExecutor

    out.mkdir(parents=True, exist_ok=True)
    rig_size = RIG_SIZE if size[0] >= RIG_SIZE[0] else size
    with ProcessPoolExecutor(max_workers=5) as pool:
        raw = pool.submit(_write, out / 'rgb8_raw.mcap', frames, size, 'rgb8')
        jpeg = pool.submit(_write, out / 'jpeg.mcap', frames, size, 'jpeg')
        stereo = pool.submit(_write_stereo, out / 'stereo.mcap', min(frames, STEREO_PAIRS))
        rig = pool.submit(_write_rig, out / 'rig.mcap', min(frames, RIG_FRAMES), rig_size)
        seg = pool.submit(_write_seg, out / 'seg.mcap', min(frames, SEG_FRAMES))
        return [raw.result(), jpeg.result(), stereo.result(), rig.result(), seg.result()]


def _write_seg(path: Path, frames: int) -> Path:
    from replaybench.fixtures.writer import write_mcap

    return write_mcap(path, frames, SEG_SIZE, 'jpeg', masks=True)


def _write_rig(path: Path, frames: int, size: tuple[int, int]) -> Path:
    from replaybench.fixtures.rig import write_rig_mcap

    return write_rig_mcap(path, frames, size, RIG_CAMERAS)


def _write_stereo(path: Path, pairs: int) -> Path:
    from replaybench.fixtures.stereo import write_stereo_mcap

    return write_stereo_mcap(path, pairs)


def _write(path: Path, frames: int, size: tuple[int, int], encoding: str) -> Path:
    from replaybench.fixtures.writer import write_mcap

    if encoding == 'jpeg':
        return write_mcap(path, frames, size, 'jpeg', compression='zstd')
    return write_mcap(path, frames, size, 'rgb8')


def _number(text: str | None) -> float | None:
    if text is None or text == '':
        return None
    try:
        return float(text)
    except ValueError:
        return None


def _device_means(frames_csv: Path) -> dict[str, dict[str, Any]]:
    """Per backend: mean device time per stage and mean host minus device time per frame, over
    the measured frames (status ok, not warm-up) that have device times."""
    per_backend: dict[str, list[dict[str, str]]] = {}
    with frames_csv.open(newline='', encoding='utf-8') as stream:
        for row in csv.DictReader(stream):
            if row.get('status') != 'ok' or row.get('warmup') != '0':
                continue
            if _number(row.get('infer_device_ms')) is None:
                continue
            per_backend.setdefault(row['backend'], []).append(row)
    result: dict[str, dict[str, Any]] = {}
    for backend, rows in sorted(per_backend.items()):
        entry: dict[str, Any] = {'frames_with_device_times': len(rows)}
        gaps = []
        for row in rows:
            host = [_number(row.get(f'{stage}_ms')) for stage in STAGES]
            device = [_number(row.get(f'{stage}_device_ms')) for stage in STAGES]
            if all(value is not None for value in host + device):
                gaps.append(sum(h for h in host if h is not None) - sum(d for d in device if d))
        for stage in STAGES:
            values = [v for r in rows if (v := _number(r.get(f'{stage}_device_ms'))) is not None]
            entry[f'{stage}_device_ms_mean'] = statistics.fmean(values) if values else None
        entry['host_minus_device_ms_mean'] = statistics.fmean(gaps) if gaps else None
        entry['host_minus_device_frames'] = len(gaps)
        result[backend] = entry
    return result


def _run_summary(folder: Path) -> dict[str, Any]:
    entry: dict[str, Any] = {'run': folder.name, 'missing': []}
    run_json = folder / 'run.json'
    if not run_json.is_file():
        entry['missing'].append('run.json')
        return entry
    run = json.loads(run_json.read_text(encoding='utf-8'))
    entry['status'] = run.get('status')
    backends: dict[str, dict[str, Any]] = {}
    for backend in run.get('backends', []):
        info = backend.get('info') or {}
        resources = (backend.get('resources') or {}).get('summary') or {}
        # keyed by the label, as summary.csv and frames.csv name it (onnx_cpu for onnx-cpu)
        backends[backend.get('label') or backend['name']] = {
            'name': backend['name'],
            'status': backend.get('status'),
            'error': backend.get('error'),
            'info': {key: info[key] for key in INFO_KEYS if key in info},
            'resources': {key: resources[key] for key in RESOURCE_KEYS if key in resources},
        }
    summary_csv = folder / 'summary.csv'
    if summary_csv.is_file():
        with summary_csv.open(newline='', encoding='utf-8') as stream:
            for row in csv.DictReader(stream):
                target = backends.setdefault(row['backend'], {})
                target.setdefault('topics', {})[row['topic']] = {
                    **{key: _number(row.get(key)) for key in SUMMARY_KEYS},
                    **{f'{s}_ms_mean': _number(row.get(f'{s}_ms_mean')) for s in STAGES},
                }
    else:
        entry['missing'].append('summary.csv')
    frames_csv = folder / 'frames.csv'
    if frames_csv.is_file():
        for backend, device in _device_means(frames_csv).items():
            backends.setdefault(backend, {})['device'] = device
    else:
        entry['missing'].append('frames.csv')
    entry['backends'] = backends
    entry['agreement'] = [
        {key: pair.get(key) for key in AGREEMENT_KEYS} for pair in run.get('agreement') or []
    ]
    entry['stereo_agreement'] = [
        {key: pair.get(key) for key in STEREO_AGREEMENT_KEYS}
        for pair in run.get('stereo_agreement') or []
    ]
    return entry


def _peak_summary(folder: Path) -> dict[str, Any] | None:
    peak_json = folder / 'peak.json'
    if not peak_json.is_file():
        return None
    peak = json.loads(peak_json.read_text(encoding='utf-8'))
    keys = ('backend', 'status', 'peak_hz', 'peak_confirmed', 'first_failing_hz', 'limit_reached')
    return {key: peak.get(key) for key in keys}


def summarise(work: Path) -> dict[str, Any]:
    """The figures of every run folder under ``work/runs`` and of ``work/peak``."""
    runs_dir = work / 'runs'
    runs = (
        [_run_summary(folder) for folder in sorted(runs_dir.iterdir()) if folder.is_dir()]
        if runs_dir.is_dir()
        else []
    )
    return {'runs': runs, 'peak': _peak_summary(work / 'peak')}


def _cell(value: Any) -> str:
    if value is None:
        return '-'
    if isinstance(value, float):
        return f'{value:.3f}'
    return str(value)


def render_markdown(summary: dict[str, Any]) -> str:
    """The summary as Markdown tables (figures as read; '-' where a file had none)."""
    lines = [
        (
            '| run | backend | topic | FPS | p50 ms | p95 ms | p99 ms | host stages ms '
            '(h2d/pre/infer/post/d2h) | device stages ms | host - device ms | engine / precision '
            '| cuda_graph | syncs/forward |'
        ),
        '|---|---|---|---|---|---|---|---|---|---|---|---|---|',
    ]
    for run in summary['runs']:
        for name, backend in (run.get('backends') or {}).items():
            info = backend.get('info') or {}
            device = backend.get('device') or {}
            topics = backend.get('topics') or {'-': {}}
            for topic, row in topics.items():
                host = '/'.join(_cell(row.get(f'{s}_ms_mean')) for s in STAGES)
                dev = '/'.join(_cell(device.get(f'{s}_device_ms_mean')) for s in STAGES)
                engine = f'{_cell(info.get("engine"))} / {_cell(info.get("precision"))}'
                cells = [
                    run['run'],
                    name,
                    topic,
                    _cell(row.get('throughput_fps')),
                    _cell(row.get('latency_ms_p50')),
                    _cell(row.get('latency_ms_p95')),
                    _cell(row.get('latency_ms_p99')),
                    host,
                    dev,
                    _cell(device.get('host_minus_device_ms_mean')),
                    engine,
                    _cell(info.get('cuda_graph')),
                    _cell(info.get('syncs_per_forward')),
                ]
                lines.append('| ' + ' | '.join(cells) + ' |')
    lines += [
        '',
        '| run | a | b | frames | n_a | n_b | matched | mean IoU | mean abs score diff |',
        '|---|---|---|---|---|---|---|---|---|',
    ]
    for run in summary['runs']:
        for pair in run.get('agreement') or []:
            keys = ('backend_a', 'backend_b', 'frames', 'n_a', 'n_b', 'matched', 'mean_iou')
            cells = [run['run'], *(_cell(pair.get(k)) for k in keys)]
            cells.append(_cell(pair.get('mean_abs_score_diff')))
            lines.append('| ' + ' | '.join(cells) + ' |')
    lines += [
        '',
        '| run | a | b | topic | pairs | EPE (px) | bad-1 | bad-2 | bad-3 | density |',
        '|---|---|---|---|---|---|---|---|---|---|',
    ]
    for run in summary['runs']:
        for pair in run.get('stereo_agreement') or []:
            cells = [run['run'], *(_cell(pair.get(k)) for k in STEREO_AGREEMENT_KEYS)]
            lines.append('| ' + ' | '.join(cells) + ' |')
    peak = summary.get('peak')
    lines += ['', f'peak: {json.dumps(peak) if peak else "no peak.json"}', '']
    return '\n'.join(lines)


def _size(text: str) -> tuple[int, int]:
    width, _, height = text.lower().partition('x')
    return int(width), int(height)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m benchmarks.gpu_steps')
    commands = parser.add_subparsers(dest='command', required=True)
    inputs = commands.add_parser(
        'inputs', help='write rgb8_raw.mcap, jpeg.mcap, stereo.mcap, rig.mcap and seg.mcap'
    )
    inputs.add_argument('out', type=Path)
    inputs.add_argument('--frames', type=int, default=300)
    inputs.add_argument('--size', type=_size, default=(1920, 1080))
    summary = commands.add_parser('summary', help='summarise the run folders')
    summary.add_argument('work', type=Path)
    summary.add_argument('out', type=Path)
    args = parser.parse_args(argv)
    if args.command == 'inputs':
        for path in write_inputs(args.out, args.frames, args.size):
            print(f'{path} {path.stat().st_size} bytes')
        return 0
    result = summarise(args.work)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'summary.json').write_text(json.dumps(result, indent=2) + '\n', encoding='utf-8')
    text = render_markdown(result)
    (args.out / 'summary.md').write_text(text, encoding='utf-8')
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
