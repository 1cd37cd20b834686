"""The JSON Schemas shipped in replaybench/schemas/ against the files a real run, peak search and
comparison write (the test session also checks every file as it is written: tests/conftest.py)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from replaybench.app.compare import main_compare
from replaybench.backends.base import BackendOptions
from replaybench.errors import OutputError
from replaybench.replay.peak import find_peak_rate
from replaybench.replay.runner import RunConfig, run_benchmark
from replaybench.results.io import (
    CHECK_SCHEMAS_ENV,
    load_schema,
    read_comparison_result,
    read_peak_result,
    read_run_result,
    schema_errors,
    to_json,
    write_run_result,
)

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
SCHEMAS = {
    'run.json': 'run.schema.json',
    'peak.json': 'peak.schema.json',
    'comparison.json': 'comparison.schema.json',
}


@pytest.fixture(scope='module')
def written(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """run.json of two real runs of the same bag, peak.json of a real peak search and the
    comparison.json of the two runs."""
    base = tmp_path_factory.mktemp('outputs')
    runs: list[Path] = []
    for name in ('a', 'b'):
        outcome = run_benchmark(
            RunConfig(inputs=[RAW], backends=['hsv', 'null'], out_dir=base / name, report=False)
        )
        assert outcome.run_dir is not None
        runs.append(outcome.run_dir)
    find_peak_rate(
        RAW,
        'null',
        base / 'peak',
        options=BackendOptions(),
        max_hz=200.0,
        refine_steps=1,
        trial_frames=10,
        report=False,
    )
    code = main_compare(runs, base / 'compare', echo=lambda _: None, echo_err=lambda _: None)
    assert code == 0
    return {
        'run.json': runs[0] / 'run.json',
        'peak.json': base / 'peak' / 'peak.json',
        'comparison.json': base / 'compare' / 'comparison.json',
    }


def _validator(file: str) -> jsonschema.Draft202012Validator:
    schema = json.loads((REPO / 'replaybench' / 'schemas' / SCHEMAS[file]).read_text('utf-8'))
    return jsonschema.Draft202012Validator(schema, format_checker=jsonschema.FormatChecker())


def _document(path: Path) -> dict[str, Any]:
    document: dict[str, Any] = json.loads(path.read_text(encoding='utf-8'))
    return document


@pytest.mark.parametrize('file', list(SCHEMAS))
def test_each_schema_is_draft_2020_12_closed_at_the_top_and_requires_schema_version(
    file: str,
) -> None:
    schema = load_schema(SCHEMAS[file])
    assert schema['$schema'] == 'https://json-schema.org/draft/2020-12/schema'
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema['additionalProperties'] is False
    assert 'schema_version' in schema['required']


@pytest.mark.parametrize('file', list(SCHEMAS))
def test_what_a_real_run_peak_and_comparison_write_matches_the_schema(
    written: dict[str, Path], file: str
) -> None:
    errors = [e.message for e in _validator(file).iter_errors(_document(written[file]))]
    assert errors == []


@pytest.mark.parametrize('file', list(SCHEMAS))
def test_a_file_with_an_unknown_top_level_key_fails_validation(
    written: dict[str, Path], file: str
) -> None:
    document = {**_document(written[file]), 'surprise': 1}
    errors = list(_validator(file).iter_errors(document))
    assert [e.validator for e in errors] == ['additionalProperties']
    assert "'surprise' was unexpected" in errors[0].message
    assert schema_errors(document, file) != []


@pytest.mark.parametrize('file', list(SCHEMAS))
def test_a_file_without_schema_version_fails_validation(
    written: dict[str, Path], file: str
) -> None:
    document = _document(written[file])
    del document['schema_version']
    assert [e.validator for e in _validator(file).iter_errors(document)] == ['required']


def test_the_model_reads_back_exactly_what_was_written(written: dict[str, Path]) -> None:
    for file, read in (
        ('run.json', read_run_result),
        ('peak.json', read_peak_result),
        ('comparison.json', read_comparison_result),
    ):
        assert to_json(read(written[file])) == _document(written[file]), file


def test_with_checks_on_a_run_json_that_breaks_its_schema_is_not_written(
    written: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    run = read_run_result(written['run.json'])
    broken = replace(run, status=None)  # type: ignore[arg-type]
    monkeypatch.setenv(CHECK_SCHEMAS_ENV, '1')
    with pytest.raises(OutputError, match=r'does not match run\.schema\.json: at status'):
        write_run_result(tmp_path / 'run.json', broken)
    assert not (tmp_path / 'run.json').exists()
    monkeypatch.setenv(CHECK_SCHEMAS_ENV, '0')
    write_run_result(tmp_path / 'run.json', broken)
    assert _document(tmp_path / 'run.json')['status'] is None
