"""run.json read through the model: what the readers show is what the writer wrote (the host in
compare's labels, the GPU a backend reports, the IoU of the agreement), and run.json records the
command line only when the CLI gives it one."""

from __future__ import annotations

import json
import platform
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from replaybench.backends.base import BackendOptions
from replaybench.comparison.runs import load_runs
from replaybench.replay.peak import find_peak_rate
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.report import render_report
from replaybench.results.agreement import AGREEMENT_IOU
from replaybench.results.io import (
    from_document,
    from_json,
    read_peak_result,
    read_run_result,
    write_run_result,
)
from replaybench.results.model import InputInfo, Resources, ResourceSummary, RunResult

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


def _run(out: Path, *backends: str) -> Path:
    outcome = run_benchmark(
        RunConfig(inputs=[RAW], backends=list(backends), out_dir=out, report=False)
    )
    assert outcome.run_dir is not None
    return outcome.run_dir


def test_compare_labels_show_the_host_a_real_run_was_measured_on(tmp_path: Path) -> None:
    host = platform.node()
    assert host, 'this machine has no host name to show'
    runs = [_run(tmp_path / name, 'null') for name in ('a', 'b')]
    assert read_run_result(runs[0]).environment.hostname == host
    infos = load_runs(runs)
    assert [i.hostname for i in infos] == [host, host]
    assert [i.label.split(' (')[0] for i in infos] == ['a', 'b']
    assert all(f'({host} / ' in i.label for i in infos)


def test_compare_names_the_gpu_a_backend_reports_and_the_one_its_use_was_sampled_on(
    tmp_path: Path,
) -> None:
    first = _run(tmp_path / 'a', 'null', 'hsv')
    run = read_run_result(first)
    null, hsv = run.backends
    assert hsv.resources is not None
    assert hsv.resources.summary is not None
    reported = replace(null, info={**null.info, 'device_name': 'NVIDIA Reported'})
    sampled = replace(
        hsv,
        resources=Resources(
            summary=replace(hsv.resources.summary, gpu_name='NVIDIA Sampled'),
            series=hsv.resources.series,
        ),
    )
    second = tmp_path / 'b'
    shutil.copytree(first, second)
    write_run_result(second / 'run.json', replace(run, backends=(reported, sampled)))
    base, gpu = load_runs([first, second])
    assert base.gpus == tuple(g.name for g in run.environment.gpus if g.name)
    assert gpu.gpus[-2:] == ('NVIDIA Reported', 'NVIDIA Sampled')
    assert 'NVIDIA Reported' in gpu.machine


def test_run_json_records_the_iou_of_the_agreement_and_the_report_states_it(
    tmp_path: Path,
) -> None:
    run_dir = _run(tmp_path / 'run', 'hsv', 'null')
    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    assert document['settings']['agreement_iou'] == AGREEMENT_IOU
    assert document['agreement'], 'two backends: one agreement row per topic'
    text = render_report(run_dir).read_text(encoding='utf-8')
    assert f'by IoU ≥ {AGREEMENT_IOU:g} (highest first)' in text
    run = read_run_result(run_dir)
    settings = replace(run.settings, agreement_iou=0.3)
    write_run_result(run_dir / 'run.json', replace(run, settings=settings))
    text = render_report(run_dir).read_text(encoding='utf-8')
    assert 'by IoU ≥ 0.3 (highest first)' in text
    assert 'the other matched (IoU ≥ 0.3, same class)' in text
    assert 'IoU ≥ 0.5' not in text


def test_an_older_run_json_without_the_host_or_the_agreement_iou_still_reads(
    tmp_path: Path,
) -> None:
    run_dir = _run(tmp_path / 'run', 'null')
    document = json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))
    del document['environment']['hostname']
    del document['settings']['agreement_iou']
    (run_dir / 'run.json').write_text(json.dumps(document), encoding='utf-8')
    run = read_run_result(run_dir)
    assert run.environment.hostname is None
    assert run.settings.agreement_iou == AGREEMENT_IOU  # what every run before used
    (info,) = load_runs([run_dir])
    assert info.label.startswith('run (')
    assert info.hostname is None


def test_a_run_started_from_python_records_no_command_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sys, 'argv', ['host-program', '--its-own-flag'])
    run_dir = _run(tmp_path / 'run', 'null')
    assert json.loads((run_dir / 'run.json').read_text(encoding='utf-8'))['command'] == []
    given = run_benchmark(
        RunConfig(
            inputs=[RAW],
            backends=['null'],
            out_dir=tmp_path / 'given',
            report=False,
            command=('replaybench', 'run', 'x.mcap'),
        )
    )
    assert given.run.command == ('replaybench', 'run', 'x.mcap')
    find_peak_rate(
        RAW,
        'null',
        tmp_path / 'peak',
        options=BackendOptions(),
        max_hz=100.0,
        refine_steps=0,
        trial_frames=10,
        report=False,
    )
    peak = read_peak_result(tmp_path / 'peak')
    assert peak.command == ()
    assert read_run_result(tmp_path / 'peak' / 'trials' / 'max').command == ()


def test_the_cli_records_its_own_command_line(tmp_path: Path) -> None:
    out = tmp_path / 'run'
    args = ['run', str(RAW), '--backend', 'null', '--out', str(out), '--no-report']
    done = subprocess.run(
        [sys.executable, '-m', 'replaybench', *args],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert read_run_result(out).command == ('replaybench', *args)


def test_a_document_built_for_writing_may_not_hold_a_key_the_model_lacks() -> None:
    with pytest.raises(TypeError, match=r'InputInfo: no field for extra'):
        from_document(InputInfo, {'path': 'a.mcap', 'extra': 1})
    with pytest.raises(
        TypeError,
        match=r'RunResult: backends\[0\]\.resources\.summary: no field for cpu_percentage',
    ):
        from_document(
            RunResult, {'backends': [{'resources': {'summary': {'cpu_percentage': 1.0}}}]}
        )
    # reading a file keeps what it knows and leaves the rest
    assert from_json(InputInfo, {'path': 'a.mcap', 'extra': 1}) == InputInfo(path='a.mcap')
    assert from_document(ResourceSummary, {'samples': 3}).samples == 3


def test_a_pickled_result_names_its_types_by_replaybench_results_model_and_loads_back_equal() -> (
    None
):
    import pickle
    import pickletools

    from replaybench.results import model

    run = model.RunResult(
        summary_rows=(
            model.SummaryRow(
                backend='aruco',
                accuracy=model.Accuracy(ap50={'tag': 1.0}),
                segmentation=model.SegmentationSummary(iou={'road': 0.5}),
                tag_accuracy=model.TagAccuracy(size_hints=(model.TagSizeHint(tag_id=14),)),
            ),
        ),
        agreement=(model.AgreementRow(disagreeing_frames=((0, 3),)),),
        segmentation_agreement=(model.SegmentationAgreementRow(miou=0.9),),
        backends=(model.BackendRun(resources=model.Resources(series=(model.ResourcePoint(),))),),
        repeats=(model.RepeatStats(repeat=1),),
    )
    peak = model.PeakResult(trial_rows=(model.PeakTrial(rate_hz=30.0),))
    comparison = model.Comparison(
        rows=(model.ComparisonRow(metrics={'latency_ms_p50': model.MetricResult(value=1.0)}),),
        gate=model.ComparisonGate(results=(model.GateCheck(condition='x'),)),
    )
    for result in (run, peak, comparison):
        data = pickle.dumps(result, protocol=2)
        named = {
            str(arg).split(' ')[0]
            for op, arg, _ in pickletools.genops(data)
            if op.name == 'GLOBAL' and str(arg).startswith('replaybench')
        }
        assert named == {'replaybench.results.model'}
        assert pickle.loads(data) == result
        assert pickle.loads(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)) == result
