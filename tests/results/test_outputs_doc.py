"""docs/outputs.md against run.schema.json: the keys the run.json examples show (the run.json
layout, the resources and the agreement entries) and the summary columns are exactly those of
the schema, so that neither can gain or lose a key without the other."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from replaybench.results.io import load_schema
from replaybench.results.stats import SUMMARY_CSV_COLUMNS

REPO = Path(__file__).resolve().parents[2]
OUTPUTS_MD = REPO / 'docs' / 'outputs.md'
SCHEMA = load_schema('run.schema.json')

#: Summary rows are documented by the summary.csv table (and these run.json-only keys).
SUMMARY_JSON_ONLY = {
    'warnings',
    'accuracy',
    'segmentation',
    'tag_accuracy',
    'task_metrics',
    'track_timeline',
}


def _section(text: str, heading: str) -> str:
    """The text of the ``## heading`` section (up to the next ``## ``)."""
    start = text.index(f'\n## {heading}')
    end = text.find('\n## ', start + 1)
    return text[start : end if end != -1 else len(text)]


def _jsonc_blocks(section: str) -> list[str]:
    return re.findall(r'```jsonc\n(.*?)```', section, flags=re.S)


def _strip(jsonc: str) -> str:
    """JSON from the documentation's JSONC: comments, ``…`` placeholders and trailing commas
    outside strings left out."""
    out: list[str] = []
    i, n, in_string = 0, len(jsonc), False
    while i < n:
        c = jsonc[i]
        if in_string:
            out.append(c)
            if c == '\\':
                out.append(jsonc[i + 1])
                i += 1
            elif c == '"':
                in_string = False
        elif c == '"':
            in_string = True
            out.append(c)
        elif jsonc.startswith('//', i):
            i = jsonc.find('\n', i)
            i = n if i == -1 else i
            continue
        elif jsonc.startswith('/*', i):
            i = jsonc.index('*/', i) + 2
            continue
        elif c != '…':
            out.append(c)
        i += 1
    text = ''.join(out)
    text = re.sub(r',(\s*,)+', ',', text)
    return re.sub(r',(\s*[\]}])', r'\1', text)


def _parse(jsonc: str) -> Any:
    import json

    text = _strip(jsonc).strip()
    if text.startswith('"'):  # a fragment: "key": value
        text = '{' + text + '}'
    return json.loads(text)


def _resolve(schema: dict[str, Any]) -> dict[str, Any]:
    """The object (or array) branch of ``schema``, its ``$ref`` followed."""
    for option in schema.get('anyOf', []) + schema.get('oneOf', []):
        if option.get('type') != 'null':
            return _resolve(option)
    ref = schema.get('$ref')
    if isinstance(ref, str):
        return _resolve(SCHEMA['$defs'][ref.rsplit('/', 1)[-1]])
    return schema


def _mismatches(doc: Any, schema: dict[str, Any], where: str, skip: set[str]) -> list[str]:
    """Where the documented object keys differ from the schema's (``{}`` and ``[]`` in the
    documentation stand for "see elsewhere" and are not compared)."""
    schema = _resolve(schema)
    found: list[str] = []
    if isinstance(doc, dict) and doc and 'properties' in schema:
        props = schema['properties']
        missing = sorted(set(props) - set(doc))
        extra = sorted(set(doc) - set(props))
        if missing:
            found.append(f'{where or "(top level)"}: the schema has {missing}, not documented')
        if extra:
            found.append(f'{where or "(top level)"}: documented {extra}, not in the schema')
        for key, value in doc.items():
            path = f'{where}.{key}' if where else key
            if key in props and path not in skip:
                found += _mismatches(value, props[key], path, skip)
    elif isinstance(doc, list) and 'items' in schema:
        objects = [item for item in doc if isinstance(item, dict)]
        if objects:  # entries may show different keys (alternatives): together, every one
            merged = {key: value for item in objects for key, value in item.items()}
            found += _mismatches(merged, schema['items'], f'{where}[]', skip)
    return found


def _summary_columns(section: str) -> list[str]:
    """The first-column names of the first table of the section (``_p90`` after
    ``latency_ms_p50`` stands for ``latency_ms_p90``)."""
    names: list[str] = []
    table = re.search(r'\n(\|.*?)\n\n', section, flags=re.S)
    assert table is not None
    for line in table.group(1).splitlines():
        if not line.startswith('| `'):
            continue
        cell = line.split('|')[1]
        for name in re.findall(r'`([^`]+)`', cell):
            if name.startswith('_') and names:
                name = names[-1].rsplit('_', 1)[0] + name
            names.append(name)
    return names


TEXT = OUTPUTS_MD.read_text(encoding='utf-8')


def test_the_run_json_layout_documents_every_key_of_the_schema_and_no_other() -> None:
    (layout,) = _jsonc_blocks(_section(TEXT, 'run.json'))
    assert _mismatches(_parse(layout), SCHEMA, '', skip={'summary'}) == []


@pytest.mark.parametrize(
    ('heading', 'schema'),
    [
        ('Resource use', SCHEMA['$defs']['BackendRun']),
        ('Agreement between backends', SCHEMA),
    ],
)
def test_the_resources_and_agreement_examples_document_every_key_of_the_schema(
    heading: str, schema: dict[str, Any]
) -> None:
    (example,) = _jsonc_blocks(_section(TEXT, heading))
    ((key, value),) = _parse(example).items()  # a fragment: "key": value
    assert _mismatches(value, schema['properties'][key], key, skip=set()) == []


def test_the_summary_columns_are_those_of_summary_csv_and_of_the_run_json_summary_rows() -> None:
    columns = _summary_columns(_section(TEXT, 'summary.csv'))
    assert sorted(columns) == sorted(SUMMARY_CSV_COLUMNS)
    row = _resolve(SCHEMA['properties']['summary']['items'])
    assert set(columns) | SUMMARY_JSON_ONLY == set(row['properties'])


def test_the_check_sees_a_key_the_documentation_lacks() -> None:
    (layout,) = _jsonc_blocks(_section(TEXT, 'run.json'))
    doc = _parse(layout)
    del doc['settings']['rate']
    doc['surprise'] = 1
    assert _mismatches(doc, SCHEMA, '', skip={'summary'}) == [
        "(top level): documented ['surprise'], not in the schema",
        "settings: the schema has ['rate'], not documented",
    ]
