"""Run folders as the comparison sees them: labels, machine facts, inputs and stability flags."""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from replaybench.results.folder import RunData, load_run
from replaybench.results.intervals import CV_LIMIT
from replaybench.results.numbers import finite_number

if TYPE_CHECKING:
    from collections.abc import Sequence

    from replaybench.results.model import RunResult

__all__ = [
    'CV_LIMIT',
    'ENGINE_KEYS',
    'SETTINGS_KEYS',
    'RunInfo',
    'engine_text',
    'inputs_match',
    'load_runs',
    'run_flags',
]

#: Keys of run.json ``backends[].info`` that identify the engine a backend ran on.
ENGINE_KEYS: tuple[str, ...] = ('engine', 'providers', 'precision')

#: Keys of run.json ``settings`` that must agree for timings to be comparable.
SETTINGS_KEYS: tuple[str, ...] = (
    'rate',
    'queue_depth',
    'warmup',
    'threads',
    'max_frames',
    'start_s',
    'duration_s',
)

_BRANDS = re.compile(r'\((?:R|TM|tm|r)\)')


def _text(value: Any) -> str | None:
    return value.strip() or None if isinstance(value, str) else None


@dataclass(frozen=True, slots=True)
class RunInfo:
    """One run folder: what was measured where, and the facts that make timings suspect."""

    index: int
    label: str
    dir: Path
    data: RunData
    status: str
    hostname: str | None
    cpu_model: str | None
    cores: int | None
    governor: str | None
    load_average: float | None
    gpus: tuple[str, ...]
    input_sha256: tuple[str | None, ...]
    input_paths: tuple[str, ...]
    truncated: bool
    settings: dict[str, Any]
    #: backend label -> run.json ``backends[].info`` (empty dict when absent)
    backend_info: dict[str, dict[str, Any]]
    #: ``label`` in three parts (``''.join`` of them is ``label``): the folder and `` (``, the
    #: machine, and ``)`` with any ``#n``; a chart shortens the machine first
    label_parts: tuple[str, str, str] = ('', '', '')

    @property
    def machine(self) -> str:
        """Host and GPU (or CPU) in a few words; '' when run.json says nothing about them."""
        device = ', '.join(dict.fromkeys(self.gpus)) or (self.cpu_model or '')
        return ' / '.join(part for part in (self.hostname, device) if part)


def engine_text(info: dict[str, Any]) -> str | None:
    """The engine facts of a backend's info (``ENGINE_KEYS``) as one line; None when it has none."""
    parts = []
    for key in ENGINE_KEYS:
        value = info.get(key)
        if value is None or value == '' or value == []:
            continue
        shown = ','.join(str(v) for v in value) if isinstance(value, list) else str(value)
        parts.append(f'{key}={shown}')
    return ' '.join(parts) or None


def _gpu_names(run: RunResult) -> tuple[str, ...]:
    """The GPUs the run used: those nvidia-smi listed, the device a GPU backend reports
    (``info.device_name``) and the one its resources were sampled on (``gpu_name``)."""
    names = [_text(g.name) for g in run.environment.gpus]
    for entry in run.backends:
        names.append(_text(entry.info.get('device_name')))
        if entry.resources is not None and entry.resources.summary is not None:
            names.append(_text(entry.resources.summary.gpu_name))
    return tuple(dict.fromkeys(n for n in names if n))


def _info(index: int, data: RunData) -> RunInfo:
    run = data.run
    env = run.environment
    cpu = env.cpu
    model = _text(cpu.model)
    if model:
        model = ' '.join(_BRANDS.sub('', model).split())
    load = env.load_average
    backends: dict[str, dict[str, Any]] = {}
    for entry in run.backends:
        label = entry.label or entry.name
        if label:
            backends.setdefault(label, dict(entry.info))
    return RunInfo(
        index=index,
        label='',
        dir=data.dir,
        data=data,
        status=run.status,
        hostname=_text(env.hostname),
        cpu_model=model,
        cores=cpu.usable_cores or cpu.logical_cores,
        governor=_text(cpu.governor),
        load_average=finite_number(load[0]) if load else None,
        gpus=_gpu_names(run),
        input_sha256=tuple(_text(i.sha256) for i in run.inputs),
        input_paths=tuple(i.path or '?' for i in run.inputs),
        truncated=any(i.truncated for i in run.inputs),
        settings={k: getattr(run.settings, k) for k in SETTINGS_KEYS},
        backend_info=backends,
    )


def _folder(path: Path) -> str:
    return path.name or path.resolve().name or str(path)


def _labels(infos: Sequence[RunInfo]) -> list[tuple[str, str, str]]:
    """Each run's label in its three parts (``RunInfo.label_parts``): unique together."""

    def label(name: str, info: RunInfo) -> tuple[str, str, str]:
        machine = info.machine
        return (f'{name} (', machine, ')') if machine else (name, '', '')

    parts = [label(_folder(i.dir), i) for i in infos]
    labels = [''.join(p) for p in parts]
    if len(set(labels)) < len(labels):
        parts = [
            label(f'{_folder(i.dir.resolve().parent)}/{_folder(i.dir)}', i)
            if labels.count(text) > 1
            else p
            for i, p, text in zip(infos, parts, labels, strict=True)
        ]
        labels = [''.join(p) for p in parts]
    seen: dict[str, int] = {}
    unique = []
    for (head, machine, tail), text in zip(parts, labels, strict=True):
        seen[text] = seen.get(text, 0) + 1
        suffix = '' if labels.count(text) == 1 else f' #{seen[text]}'
        unique.append((head, machine, tail + suffix))
    return unique


def load_runs(run_dirs: Sequence[str | Path | RunData]) -> list[RunInfo]:
    """Load run folders (SourceError naming the folder when one is not readable), labelled;
    a ``RunData`` (a run held in memory) is taken as it is."""
    infos = [
        _info(index, d if isinstance(d, RunData) else load_run(Path(d)))
        for index, d in enumerate(run_dirs)
    ]
    return [
        replace(i, label=''.join(parts), label_parts=parts)
        for i, parts in zip(infos, _labels(infos), strict=True)
    ]


def inputs_match(info: RunInfo, baseline: RunInfo) -> bool | None:
    """True when both runs replayed the same files (same sha256, same order); None when unknown."""
    if len(info.input_sha256) != len(baseline.input_sha256):
        return False
    pairs = list(zip(info.input_sha256, baseline.input_sha256, strict=True))
    if any(a is not None and b is not None and a != b for a, b in pairs):
        return False
    if not pairs or any(a is None or b is None for a, b in pairs):
        return None
    return True


def run_flags(info: RunInfo, baseline: RunInfo) -> list[str]:
    """Facts about one run that make its timings doubtful or not comparable with the baseline."""
    flags: list[str] = []
    if info.status != 'complete':
        flags.append(f'run status {info.status}')
    if info.truncated:
        flags.append('an input was truncated')
    if info.governor is not None and info.governor != 'performance':
        flags.append(f'CPU governor {info.governor} (not performance)')
    if info.load_average is not None and info.cores and info.load_average > info.cores / 2:
        flags.append(f'load average {info.load_average:g} above half of {info.cores} cores')
    if info.index != baseline.index:
        match = inputs_match(info, baseline)
        if match is False:
            flags.append('inputs differ from the baseline (sha256)')
        elif match is None:
            flags.append('inputs not checked: sha256 missing in run.json')
        if info.gpus != baseline.gpus and (info.gpus or baseline.gpus):
            mine = ', '.join(info.gpus) or 'none'
            theirs = ', '.join(baseline.gpus) or 'none'
            flags.append(f'GPU differs from the baseline: {mine} vs {theirs}')
        changed = [
            f'{key} {info.settings.get(key)} vs {baseline.settings.get(key)}'
            for key in SETTINGS_KEYS
            if info.settings.get(key) != baseline.settings.get(key)
        ]
        if changed:
            flags.append('settings differ from the baseline: ' + ', '.join(changed))
    return flags
