"""The benchmark suite still runs end to end (tiny data) and writes a complete bench.json."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ITEMS = {'a', 'b', 'c', 'd', 'e'}


def test_quick_benchmark_suite_writes_every_item_with_repeats_and_targets(tmp_path: Path) -> None:
    out = tmp_path / 'bench.json'
    proc = subprocess.run(
        [sys.executable, '-m', 'benchmarks', '--quick', '--out', str(out)],
        cwd=REPO,
        env={**os.environ, 'TMPDIR': str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    document = json.loads(out.read_text(encoding='utf-8'))
    assert document['schema_version'] == 1
    assert document['mode'] == 'quick'
    assert document['threads']['cv2.getNumThreads'] == 1
    assert document['environment']['cpu']['logical_cores'] >= 1
    items = {item['item']: item for item in document['items']}
    assert set(items) >= ITEMS
    for name in ITEMS:
        item = items[name]
        assert item['skipped'] is None, item['skipped']
        assert item['checks'], name
        for m in item['measurements']:
            assert m['repeats'], m['name']
            assert min(m['repeats']) == m['min'] <= m['median'] <= m['max'] == max(m['repeats'])
            assert m['median'] > 0, m['name']
        for check in item['checks']:
            assert check['low'] <= check['value'] <= check['high'], check['name']
            assert check['passed'] in (True, False, None)
    targeted = [c for item in document['items'] for c in item['checks'] if c['target'] is not None]
    assert document['totals']['checks'] == len(targeted)
    assert document['totals']['passed'] + document['totals']['failed'] == len(targeted)
    # hsv and the naive port agree on every frame, whatever the timings say
    counts = [c for c in items['c']['checks'] if c['name'].startswith('same detection count')]
    assert counts
    assert all(c['value'] == 1.0 for c in counts)
    assert 'PASS' in proc.stdout or 'FAIL' in proc.stdout
    assert not list(tmp_path.glob('replaybench-bench-*')), 'temporary bags were left behind'
