"""Planning a sweep without Ray: --param grids, cell options and keys, input identity, the
authentication settings for Ray, and usage errors of the `sweep` command."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from replaybench.app.options import RunOptions
from replaybench.app.sweep import (
    cell_options,
    input_identity,
    join_auth_env,
    parse_params,
    plan_cells,
)
from replaybench.backends.base import BackendOptions
from replaybench.errors import SourceError, UsageError

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'fixtures' / 'bags' / 'jpeg.mcap'


def test_a_param_grid_gives_one_cell_per_combination_for_its_backend_only() -> None:
    axes = parse_params(['hsv.min_area=50,100,200', 'hsv.kernel=3,5'], ['hsv', 'null'])
    inputs = [input_identity(BAG), input_identity(REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap')]
    cells = plan_cells(inputs, ['hsv', 'null'], axes, RunOptions())
    assert len(cells) == 2 * (3 * 2 + 1)
    first = [c for c in cells if c.input_index == 0]
    assert [c.params for c in first if c.backend == 'hsv'] == [
        (('min_area', a), ('kernel', k)) for a in ('50', '100', '200') for k in ('3', '5')
    ]
    assert [c.params for c in first if c.backend == 'null'] == [()]
    assert len({c.key for c in cells}) == len(cells)
    assert len({c.name for c in cells}) == len(cells)
    assert [c.index for c in cells] == list(range(len(cells)))


@pytest.mark.parametrize(
    ('text', 'needle'),
    [
        ('hsv.min_area', 'use BACKEND.KEY=V1,V2'),
        ('min_area=50', 'use BACKEND.KEY=V1,V2'),
        ('onnx-cpu.conf=0.3', "backend 'onnx-cpu' is not swept"),
        ('hsv.min_area=50,,100', 'empty value'),
        ('hsv.min_area=50,50', 'given twice'),
        ('hsv.device=0,1', 'chosen by Ray'),
    ],
)
def test_a_malformed_param_is_refused_with_the_reason(text: str, needle: str) -> None:
    with pytest.raises(UsageError, match=needle):
        parse_params([text], ['hsv'])


def test_the_same_param_twice_is_refused() -> None:
    with pytest.raises(UsageError, match='given twice'):
        parse_params(['hsv.min_area=1', 'hsv.min_area=2'], ['hsv'])


def test_params_set_typed_options_and_backend_extras() -> None:
    base = BackendOptions(threads=2, extra={'max_det': '10'})
    found = cell_options(base, {'conf': '0.4', 'threads': '3', 'model': 'm.onnx', 'min_area': '50'})
    assert found.conf == 0.4
    assert found.threads == 3
    assert found.model == Path('m.onnx')
    assert dict(found.extra) == {'max_det': '10', 'min_area': '50'}
    with pytest.raises(UsageError, match='expected a number') as caught:
        cell_options(base, {'iou': 'high'})
    assert isinstance(caught.value.__cause__, ValueError)
    with pytest.raises(UsageError, match='integer >= 1'):
        cell_options(base, {'threads': '0'})


def test_a_cell_key_changes_with_options_input_and_version(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    bag = tmp_path / 'a.mcap'
    bag.write_bytes(BAG.read_bytes())
    inp = input_identity(bag)

    def key(settings: RunOptions, params: tuple[tuple[str, str], ...] = ()) -> str:
        axes = parse_params([f'hsv.{k}={v}' for k, v in params], ['hsv'])
        return plan_cells([inp], ['hsv'], axes, settings)[0].key

    base = key(RunOptions(max_frames=5))
    assert key(RunOptions(max_frames=5)) == base
    assert key(RunOptions(max_frames=6)) != base
    assert key(RunOptions(max_frames=5), (('min_area', '50'),)) != base
    config = tmp_path / 'hsv.toml'
    config.write_text('[detector]\nmin_area = 10.0\n')
    with_config = key(RunOptions(max_frames=5, config=config))
    config.write_text('[detector]\nmin_area = 20.0\n')
    assert key(RunOptions(max_frames=5, config=config)) != with_config
    monkeypatch.setattr('replaybench._version.__version__', '99.0.0')
    assert key(RunOptions(max_frames=5)) != base
    monkeypatch.undo()
    bag.write_bytes(BAG.read_bytes() + b'\0')
    inp = input_identity(bag)
    assert key(RunOptions(max_frames=5)) != base


def test_the_identity_of_a_rosbag2_folder_is_the_digest_of_its_data_files(tmp_path: Path) -> None:
    from replaybench.fixtures.writer import write_rosbag2
    from replaybench.sources.digest import files_sha256

    folder = write_rosbag2(tmp_path / 'bag2', frames=3, size=(32, 24))
    found = input_identity(folder)
    data = sorted(p for p in folder.iterdir() if p.name != 'metadata.yaml')
    assert found.sha256 == files_sha256(data)
    assert found.size_bytes == sum(p.stat().st_size for p in data)
    assert [s.path for s in found.files] == [p.resolve() for p in data]
    before = found.sha256
    with (folder / 'metadata.yaml').open('a') as f:  # not a data file: the digest stays
        f.write('# note\n')
    assert input_identity(folder).sha256 == before
    assert input_identity(folder, digest=False).sha256 is None


def test_a_missing_input_or_a_fifo_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SourceError, match='no such file'):
        input_identity(tmp_path / 'nothing.mcap')
    fifo = tmp_path / 'pipe.mcap'
    os.mkfifo(fifo)
    with pytest.raises(SourceError, match='not a regular file'):
        input_identity(fifo)


def test_a_local_instance_uses_a_token_of_the_process_and_never_the_home_folder() -> None:
    found = join_auth_env(None, {})
    assert found['RAY_AUTH_MODE'] == 'token'
    assert len(found['RAY_AUTH_TOKEN']) == 64
    assert join_auth_env(None, {})['RAY_AUTH_TOKEN'] == found['RAY_AUTH_TOKEN']
    assert join_auth_env(None, {'RAY_AUTH_TOKEN': 'mine'})['RAY_AUTH_TOKEN'] == 'mine'
    assert join_auth_env(None, {'RAY_AUTH_MODE': 'disabled'}) == {}


def test_joining_a_cluster_uses_token_mode_only_when_a_token_is_at_hand(tmp_path: Path) -> None:
    home = tmp_path / 'home'
    home.mkdir()
    address = 'head:6379'
    assert join_auth_env(address, {}, home) == {}
    assert join_auth_env(address, {'RAY_AUTH_TOKEN': 't'}, home) == {'RAY_AUTH_MODE': 'token'}
    path = tmp_path / 'token'
    assert join_auth_env(address, {'RAY_AUTH_TOKEN_PATH': str(path)}, home) == {}
    path.write_text('t')
    found = join_auth_env(address, {'RAY_AUTH_TOKEN_PATH': str(path)}, home)
    assert found == {'RAY_AUTH_MODE': 'token'}
    (home / '.ray').mkdir()
    (home / '.ray' / 'auth_token').write_text('t')
    assert join_auth_env(address, {}, home) == {'RAY_AUTH_MODE': 'token'}
    assert join_auth_env(address, {'RAY_AUTH_MODE': 'disabled'}, home) == {}


def _cli(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, '-m', 'replaybench', 'sweep', *args],
        cwd=tmp_path,
        env={**os.environ, 'HOME': str(tmp_path)},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


@pytest.mark.parametrize(
    ('args', 'needle'),
    [
        (['--backend', 'hsv', '--param', 'hsv.min_area'], 'invalid --param'),
        (['--backend', 'hsv', '--param', 'hsv.colour=1'], "hsv: unknown option 'colour'"),
        (['--backend', 'hsv', '--param', 'hsv.min_area=big'], 'is not a number'),
        (['--backend', 'nosuch'], "unknown backend 'nosuch'"),
        ([], 'no backend given'),
        (['--backend', 'hsv', '--rate', 'fast'], 'rate'),
    ],
)
def test_bad_options_end_the_sweep_command_with_one_line_and_exit_2_before_ray_starts(
    tmp_path: Path, args: list[str], needle: str
) -> None:
    proc = _cli(tmp_path, str(BAG), '--out', 'sw', *args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith('replaybench: error: ')
    assert needle in lines[0]
    assert not (tmp_path / 'sw').exists()
    assert not (tmp_path / '.ray').exists()


def test_an_output_folder_holding_something_else_is_refused(tmp_path: Path) -> None:
    (tmp_path / 'sw').mkdir()
    (tmp_path / 'sw' / 'notes.txt').write_text('mine')
    proc = _cli(tmp_path, str(BAG), '--out', 'sw', '--backend', 'null')
    assert proc.returncode == 2
    assert 'holds no sweep' in proc.stderr
    assert sorted(p.name for p in (tmp_path / 'sw').iterdir()) == ['notes.txt']


def test_a_missing_input_is_refused_before_ray_starts(tmp_path: Path) -> None:
    proc = _cli(tmp_path, str(tmp_path / 'gone.mcap'), '--out', 'sw', '--backend', 'null')
    assert proc.returncode == 2
    assert (
        proc.stderr.strip()
        == f'replaybench: error: {tmp_path / "gone.mcap"}: no such file or directory'
    )


def test_a_node_checks_the_input_by_size_and_time_and_hashes_only_when_the_times_differ(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import replaybench.sources.digest as digest
    from replaybench.app.sweep.cell import check_input

    bag = tmp_path / 'a.mcap'
    bag.write_bytes(BAG.read_bytes())
    inp = input_identity(bag)
    hashed: list[object] = []
    real = digest.files_sha256

    def counted(files: object, **kwargs: object) -> str:
        hashed.append(files)
        return real(files, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(digest, 'files_sha256', counted)
    check_input(inp, 'node')
    assert hashed == []  # same sizes and times: no digest on the node
    stat = bag.stat()
    os.utime(bag, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    check_input(inp, 'node')  # another time, the same bytes
    assert len(hashed) == 1
    data = bytearray(bag.read_bytes())
    data[-1] ^= 0xFF
    bag.write_bytes(bytes(data))
    with pytest.raises(SourceError, match=r"differs from the driver's copy \(sha256"):
        check_input(inp, 'node')
    bag.write_bytes(bytes(data) + b'\0')
    with pytest.raises(SourceError, match='bytes instead of'):
        check_input(inp, 'node')
    assert len(hashed) == 2  # a size that differs needs no digest
    bag.unlink()
    with pytest.raises(SourceError, match='is not readable on node node'):
        check_input(inp, 'node')
