"""docs/ci.md: its GitHub Actions workflow and its GitLab CI job parse as YAML, and their shell
steps run as written, with replaybench from this environment, on the CI bag.

Each file is run twice, as its CI system would run it: first as a push to the main branch (it
measures the bag and keeps the run as the baseline), then as a pull / merge request (it measures
again, gates against the baseline, writes the Markdown summary and the trend figures). The
steps that install the project or call another action (``uses:``) are the CI system's own and
are not run here; a step's ``if:`` is evaluated for the event.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

yaml = pytest.importorskip('yaml')

REPO = Path(__file__).resolve().parents[1]
CI_MD = REPO / 'docs' / 'ci.md'
STEP_TIMEOUT_S = 300


def _yaml_blocks() -> list[dict[str, Any]]:
    text = CI_MD.read_text(encoding='utf-8')
    blocks = re.findall(r'^```yaml\n(.*?)^```', text, flags=re.S | re.M)
    return [yaml.safe_load(block) for block in blocks]


def _workspace(tmp_path: Path) -> Path:
    work = tmp_path / 'repo'
    (work / 'fixtures' / 'bags').mkdir(parents=True)
    shutil.copy2(REPO / 'fixtures' / 'bags' / 'ci.mcap', work / 'fixtures' / 'bags' / 'ci.mcap')
    return work


def _env(extra: dict[str, str]) -> dict[str, str]:
    env = dict(os.environ)
    env['PATH'] = f'{Path(sys.executable).parent}{os.pathsep}{env.get("PATH", "")}'
    env.update({k: str(v) for k, v in extra.items()})
    return env


def _shell(script: str, cwd: Path, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ['bash', '-e', '-c', script],
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=STEP_TIMEOUT_S,
        check=False,
    )


def _github_if(condition: str | None, event: str) -> bool:
    """The few expressions the workflow uses: always(), github.event_name == '...', &&."""
    if condition is None:
        return True
    allowed = r"^(always\(\)|github\.event_name == '\w+'|\s|&&)+$"
    assert re.match(allowed, condition), f'unexpected if: {condition!r}'
    python = condition.replace('always()', 'True').replace('&&', 'and')
    python = python.replace('github.event_name', repr(event))
    return bool(eval(python, {'__builtins__': {}}))


def _own_step(step: dict[str, Any]) -> bool:
    return 'uses' in step or 'pip install' in step.get('run', '')


def _check_outputs(work: Path, summary: Path) -> None:
    assert (work / 'runs' / 'baseline' / 'run.json').is_file()
    text = summary.read_text(encoding='utf-8')
    assert 'replaybench gate' in text
    assert '| run | backend | topic |' in text
    for name in ('smaller_is_better.json', 'bigger_is_better.json'):
        entries = json.loads((work / 'bench' / name).read_text(encoding='utf-8'))
        assert entries
        assert all({'name', 'unit', 'value'} <= set(e) for e in entries)


def test_ci_md_holds_a_github_workflow_and_a_gitlab_job() -> None:
    github, gitlab = _yaml_blocks()
    steps = github['jobs']['perf']['steps']
    assert [s['name'] for s in steps if 'name' in s][:1] == ['Install']
    assert any('--markdown' in s.get('run', '') for s in steps)
    assert any('GITHUB_STEP_SUMMARY' in s.get('run', '') for s in steps)
    assert any(s.get('uses', '').startswith('benchmark-action/') for s in steps)
    job = gitlab['replaybench']
    assert job['artifacts']['when'] == 'always'
    assert 'summary.md' in job['artifacts']['paths']


@pytest.mark.quiet
def test_the_github_workflow_keeps_a_baseline_then_gates_a_pull_request(tmp_path) -> None:
    github, _ = _yaml_blocks()
    work = _workspace(tmp_path)
    summary = tmp_path / 'step_summary.md'
    summary.write_text('', encoding='utf-8')
    for event in ('push', 'pull_request'):
        env = _env(
            {**github.get('env', {}), 'GITHUB_EVENT_NAME': event, 'GITHUB_STEP_SUMMARY': summary}
        )
        for step in github['jobs']['perf']['steps']:
            if _own_step(step) or not _github_if(step.get('if'), event):
                continue
            done = _shell(step['run'], work, env)
            assert done.returncode == 0, (event, step['name'], done.stdout, done.stderr)
    _check_outputs(work, summary)


@pytest.mark.quiet
def test_the_gitlab_job_keeps_a_baseline_then_gates_a_merge_request(tmp_path) -> None:
    _, gitlab = _yaml_blocks()
    job = gitlab['replaybench']
    work = _workspace(tmp_path)
    for source in ('push', 'merge_request_event'):
        env = _env({**job['variables'], 'CI_PIPELINE_SOURCE': source})
        for line in job['script']:
            done = _shell(line, work, env)
            assert done.returncode == 0, (source, line, done.stdout, done.stderr)
    for path in job['artifacts']['paths']:
        assert (work / path).exists(), path
    _check_outputs(work, work / 'summary.md')
