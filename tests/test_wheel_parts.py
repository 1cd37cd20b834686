"""benchmarks/wheel_parts.py: a wheel cut into parts joins back to the same bytes, installs
offline from there, and parts that are missing, altered or unlisted are refused in one line
(exit 2) without writing a wheel. The wheel here is a real one, built with its metadata and
RECORD as pip reads them; its module is imported from the folder pip installed it to."""

from __future__ import annotations

import base64
import hashlib
import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # the benchmarks package, however pytest was started
    sys.path.insert(0, str(REPO))

from benchmarks.wheel_parts import (  # noqa: E402 - after the path above
    DEFAULT_PART_MIB,
    MIB,
    PartsError,
    calls,
    join,
    main,
    split,
)

#: what one device call may carry, the working tree included (the device tool's limit)
CARRY_LIMIT = 64 * MIB


def _record_line(name: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b'=').decode()
    return f'{name},sha256={digest},{len(data)}'


@pytest.fixture(scope='module')
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A pure-Python wheel of 2.5 MiB (incompressible payload, stored) whose module says
    what it holds."""
    payload = os.urandom(2 * MIB + MIB // 2)
    files = {
        'rbparts_probe/__init__.py': (
            f"import pathlib\nSIZE = (pathlib.Path(__file__).parent / 'payload.bin')"
            f'.stat().st_size\nDIGEST = {hashlib.sha256(payload).hexdigest()!r}\n'
        ).encode(),
        'rbparts_probe/payload.bin': payload,
        'rbparts_probe-1.0.dist-info/METADATA': (
            b'Metadata-Version: 2.1\nName: rbparts-probe\nVersion: 1.0\n'
        ),
        'rbparts_probe-1.0.dist-info/WHEEL': (
            b'Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n'
        ),
    }
    record_name = 'rbparts_probe-1.0.dist-info/RECORD'
    record = '\n'.join([*(_record_line(n, d) for n, d in files.items()), f'{record_name},,'])
    path = tmp_path_factory.mktemp('wheel') / 'rbparts_probe-1.0-py3-none-any.whl'
    with zipfile.ZipFile(path, 'w', zipfile.ZIP_STORED) as z:
        for name, data in files.items():
            z.writestr(name, data)
        z.writestr(record_name, record + '\n')
    return path


def test_parts_join_to_the_same_bytes_and_the_wheel_installs_offline_and_imports(
    wheel: Path, tmp_path: Path
) -> None:
    manifest = split(wheel, tmp_path / 'parts', part_mib=1)
    assert [p['name'] for p in manifest['parts']] == ['part-01.bin', 'part-02.bin', 'part-03.bin']
    assert [p['size'] for p in manifest['parts']][:2] == [MIB, MIB]
    assert max(p['size'] for p in manifest['parts']) <= MIB
    joined = join(tmp_path / 'parts', tmp_path / 'whl')
    assert joined.name == wheel.name
    assert joined.read_bytes() == wheel.read_bytes()
    site = tmp_path / 'site'
    install = [
        sys.executable, '-m', 'pip', 'install', '-q', '--no-index', '--no-deps', '--no-compile',
        '--target', str(site), str(joined),
    ]  # fmt: skip
    subprocess.run(install, check=True, capture_output=True, timeout=120)
    probe = 'import rbparts_probe as p; print(p.__file__, p.SIZE, p.DIGEST)'
    env = {**os.environ, 'PYTHONPATH': str(site)}
    done = subprocess.run(
        [sys.executable, '-c', probe], env=env, capture_output=True, text=True, check=True
    )
    where, size, digest = done.stdout.split()
    assert Path(where).is_relative_to(site)
    with zipfile.ZipFile(wheel) as z:
        payload = z.read('rbparts_probe/payload.bin')
    assert (int(size), digest) == (len(payload), hashlib.sha256(payload).hexdigest())


@pytest.mark.parametrize('damage', ['missing', 'altered', 'truncated', 'no manifest'])
def test_damaged_parts_are_one_line_exit_2_and_no_wheel_is_written(
    wheel: Path, tmp_path: Path, damage: str, capsys: pytest.CaptureFixture[str]
) -> None:
    parts = tmp_path / 'parts'
    split(wheel, parts, part_mib=1)
    if damage == 'missing':
        (parts / 'part-02.bin').unlink()
    elif damage == 'altered':
        data = bytearray((parts / 'part-02.bin').read_bytes())
        data[100] ^= 0xFF
        (parts / 'part-02.bin').write_bytes(bytes(data))
    elif damage == 'truncated':
        (parts / 'part-03.bin').write_bytes((parts / 'part-03.bin').read_bytes()[:-1])
    else:
        (parts / 'manifest.json').unlink()
    with pytest.raises(PartsError):
        join(parts, tmp_path / 'whl')
    assert main(['join', str(parts), str(tmp_path / 'whl')]) == 2
    err = capsys.readouterr().err
    assert err.startswith('wheel_parts: error: ')
    assert err.count('\n') == 1
    assert not (tmp_path / 'whl').exists() or not list((tmp_path / 'whl').iterdir())


def test_the_device_calls_carry_one_part_each_the_manifest_first_and_join_last(
    wheel: Path, tmp_path: Path
) -> None:
    parts = tmp_path / 'parts'
    split(wheel, parts, part_mib=1)
    planned = calls(parts)
    assert len(planned) == 3
    assert planned[0][0] == [f'{parts.as_posix()}/part-01.bin', f'{parts.as_posix()}/manifest.json']
    assert planned[1][0] == [f'{parts.as_posix()}/part-02.bin']
    assert planned[2][0] == [f'{parts.as_posix()}/part-03.bin', '.whl']
    assert planned[2][1].startswith(f'python3 -m benchmarks.wheel_parts join {parts.as_posix()}')
    assert planned[2][1].endswith('benchmarks/gpu_check.sh --out $OUT')
    one = tmp_path / 'one'
    split(wheel, one, part_mib=4)  # a single part: the manifest travels with it
    assert calls(one) == [
        (
            [f'{one.as_posix()}/part-01.bin', f'{one.as_posix()}/manifest.json', '.whl'],
            planned[2][1].replace(parts.as_posix(), one.as_posix()),
        )
    ]
    printed = subprocess.run(
        [sys.executable, '-m', 'benchmarks.wheel_parts', 'calls', str(parts)],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.splitlines()
    assert [json.loads(line)['carry'] for line in printed] == [c for c, _ in planned]


def test_a_default_part_and_the_tracked_tree_fit_one_carry() -> None:
    """Where the tree grows past it, lower DEFAULT_PART_MIB (docs/gpu.md names the sizes)."""
    listed = subprocess.run(
        ['git', 'ls-files', '-z'], cwd=REPO, capture_output=True, check=True
    ).stdout.split(b'\0')
    tree = sum((REPO / os.fsdecode(name)).stat().st_size for name in listed if name)
    assert tree + DEFAULT_PART_MIB * MIB + MIB <= CARRY_LIMIT, tree / MIB


def test_a_part_size_under_1_mib_is_refused(wheel: Path, tmp_path: Path) -> None:
    with pytest.raises(PartsError, match='at least 1'):
        split(wheel, tmp_path / 'parts', part_mib=0)
