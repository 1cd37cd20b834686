"""The run folder's life cycle: nothing lost, nothing invented.

A run is written beside OUT and swapped in whole when it ends, so a failed attempt leaves the
previous run byte for byte and no folder of its own; a run that measured no frame is refused;
a backend that raises is recorded and the others finish.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bagtools import TS, Header, Time, image_msg, noise_frames, write_mcap

from replaybench.app.run import RunConfig, run_benchmark
from replaybench.backends.base import BackendOptions
from replaybench.backends.null import NullBackend
from replaybench.errors import BackendError, BackendFailedError, DecodeError, UsageError
from replaybench.replay import Rate, VirtualClock

if TYPE_CHECKING:
    from replaybench.types import BackendResult, Frame

NS = 1_000_000_000
T0 = 1_700_000_000 * NS
TOPIC = '/cam/image_raw'


def _bag(path: Path, n: int = 20, hz: int = 30, gap_after: int | None = None) -> Path:
    """n raw frames at ``hz``; with ``gap_after``, a 5 s gap after that many frames."""
    frames = noise_frames(n)
    messages = []
    for i in range(n):
        t = T0 + i * NS // hz
        if gap_after is not None and i >= gap_after:
            t += 5 * NS
        messages.append((TOPIC, t, image_msg(t, frames[i]), 'sensor_msgs/msg/Image'))
    write_mcap(path, messages)
    return path


def _jpeg_bag(path: Path, n: int = 20) -> Path:
    """n 640x480 JPEG frames: slow enough to decode that a max-rate pass reads them ahead."""
    import cv2

    compressed = TS.types['sensor_msgs/msg/CompressedImage']
    rng = np.random.default_rng(3)
    messages = []
    for i in range(n):
        t = T0 + i * NS // 30
        pixels = rng.integers(0, 255, size=(480, 640, 3), dtype=np.uint8)
        ok, data = cv2.imencode('.jpg', pixels, [cv2.IMWRITE_JPEG_QUALITY, 95])
        assert ok
        msg = compressed(
            header=Header(stamp=Time(sec=t // NS, nanosec=t % NS), frame_id='cam'),
            format='jpeg',
            data=np.frombuffer(data.tobytes(), dtype=np.uint8),
        )
        messages.append(('/cam/image_raw/compressed', t, msg, 'sensor_msgs/msg/CompressedImage'))
    write_mcap(path, messages)
    return path


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry under ``folder``: file contents, None for folders."""
    return {
        str(p.relative_to(folder)): None if p.is_dir() else p.read_bytes()
        for p in sorted(folder.rglob('*'))
    }


def _rows(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / 'frames.csv').open(newline='') as f:
        return list(csv.DictReader(f))


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, '-c', 'pass'])
    process.wait()
    return process.pid


class Boom(NullBackend):
    """The null backend, raising at one seq (every frame from it on, were it called again)."""

    name: ClassVar[str] = 'boom'
    at_seq: ClassVar[int] = 5

    def detect(self, frame: Frame) -> BackendResult:
        if frame.seq >= self.at_seq:
            msg = f'boom at {frame.seq}'
            raise RuntimeError(msg)
        return super().detect(frame)


def _factory(name: str, options: BackendOptions) -> Any:
    return Boom(options) if name == 'boom' else NullBackend(options)


def _previous_run(bag: Path, out: Path) -> dict[str, bytes | None]:
    run_benchmark(RunConfig(inputs=[bag], backends=['null'], out_dir=out))
    assert (out / 'report.html').is_file()
    return _snapshot(out)


# -- --force: the previous run is replaced only by a run that finished -------------------------


def test_a_forced_run_that_fails_before_the_replay_leaves_the_previous_run_byte_for_byte(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap')
    out = tmp_path / 'run'
    before = _previous_run(bag, out)
    model = tmp_path / 'model.onnx'
    model.write_text('not a model\n')
    with pytest.raises(BackendError, match='cannot load'):
        run_benchmark(
            RunConfig(
                inputs=[bag],
                backends=['onnx-cpu'],
                out_dir=out,
                force=True,
                options=BackendOptions(model=model),
            )
        )
    assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'model.onnx', 'run']


def test_a_forced_run_whose_only_backend_raises_leaves_the_previous_run_byte_for_byte(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap')
    out = tmp_path / 'run'
    before = _previous_run(bag, out)
    with pytest.raises(BackendError, match='boom at 5') as caught:
        run_benchmark(
            RunConfig(inputs=[bag], backends=['boom'], out_dir=out, force=True),
            backend_factory=_factory,
        )
    assert caught.value.exit_code == 1
    assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'run']


def test_a_successful_forced_run_leaves_only_the_new_runs_files(tmp_path: Path) -> None:
    bag = _bag(tmp_path / 'cam.mcap')
    out = tmp_path / 'run'
    _previous_run(bag, out)
    (out / 'notes.txt').write_text('left by the old run')
    (out / 'samples' / 'input7_old.jpg').write_bytes(b'old')
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=out, force=True, report=False)
    )
    assert outcome.run_dir == out
    fresh = run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'fresh', report=False)
    )
    assert fresh.run_dir is not None
    assert sorted(_snapshot(out)) == sorted(_snapshot(fresh.run_dir))
    assert not (out / 'report.html').exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'fresh', 'run']


def test_a_forced_run_refuses_to_replace_a_folder_that_is_not_a_run_folder(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=3)
    out = tmp_path / 'photos'
    out.mkdir()
    (out / 'holiday.jpg').write_bytes(b'mine')
    with pytest.raises(UsageError, match=r'not a run folder \(no run.json\)'):
        run_benchmark(RunConfig(inputs=[bag], backends=['null'], out_dir=out, force=True))
    assert _snapshot(out) == {'holiday.jpg': b'mine'}
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'photos']


def test_a_temporary_folder_left_by_a_killed_run_is_removed_by_the_next_run(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=3)
    stale = tmp_path / f'.run.tmp-{_dead_pid()}'
    stale.mkdir()
    (stale / 'frames.csv.part').write_text('input,backend\r\n0,nu')
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run', report=False)
    )
    assert outcome.status == 'complete'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'run']


def test_a_previous_run_set_aside_by_a_crash_during_the_swap_is_put_back(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=3)
    out = tmp_path / 'run'
    before = _previous_run(bag, out)
    # a crash between the two renames of the swap: the old run renamed aside, the new not in
    out.rename(tmp_path / f'.run.old-{_dead_pid()}')
    with pytest.raises(UsageError, match='not empty'):
        run_benchmark(RunConfig(inputs=[bag], backends=['null'], out_dir=out))
    assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'run']


# -- a run that measured no frame is refused, and leaves nothing -------------------------------


@pytest.mark.parametrize(
    ('window', 'gap'),
    [
        ({'start_s': 100.0}, False),
        ({'duration_s': 0.0}, False),
        ({'start_s': 2.0, 'duration_s': 1.0}, True),
    ],
    ids=['start past the end', 'duration 0', 'window in a gap'],
)
def test_a_time_window_without_frames_exits_2_and_writes_nothing(
    tmp_path: Path, window: dict[str, Any], gap: bool
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', n=10, gap_after=5 if gap else None)
    with pytest.raises(UsageError, match='no frame was measured') as caught:
        run_benchmark(
            RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run', **window)
        )
    assert caught.value.exit_code == 2
    assert 'no image message' in str(caught.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap']


def test_a_bag_where_no_frame_decodes_exits_2_and_leaves_no_run_json(tmp_path):
    frames = noise_frames(3)
    bag = tmp_path / 'allbad.mcap'
    write_mcap(
        bag,
        [
            (TOPIC, i, image_msg(i, frames[i], data=bytes(10)), 'sensor_msgs/msg/Image')
            for i in range(3)
        ],
    )
    with pytest.raises(DecodeError, match='no frame was measured') as caught:
        run_benchmark(RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run'))
    assert caught.value.exit_code == 2
    assert 'could be decoded' in str(caught.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['allbad.mcap']


def test_an_explicit_warmup_of_every_frame_is_clamped_so_one_frame_is_measured(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=5)
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run', warmup=50)
    )
    run = outcome.run
    assert run.settings.warmup == 50
    assert run.settings.warmup_per_topic == {TOPIC: 4}
    assert [s.measured for s in run.summary_rows] == [1]
    assert any('--warmup 50' in w and TOPIC in w for w in run.warnings)
    assert outcome.run_dir is not None
    rows = _rows(outcome.run_dir)
    assert [r['warmup'] for r in rows] == ['1', '1', '1', '1', '0']


def test_a_warmup_that_leaves_a_frame_to_measure_is_kept_without_a_warning(tmp_path):
    bag = _bag(tmp_path / 'cam.mcap', n=5)
    outcome = run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=tmp_path / 'run', warmup=4)
    )
    assert outcome.run.settings.warmup_per_topic == {TOPIC: 4}
    assert outcome.run.warnings == ()


# -- a backend that raises is recorded; the others finish ---------------------------------------


@pytest.mark.parametrize(
    'mode', ['max inline', 'max read ahead', 'fixed rate'], ids=lambda m: m.replace(' ', '-')
)
def test_a_backend_that_raises_is_stopped_and_recorded_while_the_others_finish(
    tmp_path: Path, mode: str
) -> None:
    from mcap.reader import make_reader

    if mode == 'max read ahead':
        bag, topic = _jpeg_bag(tmp_path / 'cam.mcap'), '/cam/image_raw/compressed'
    else:
        bag, topic = _bag(tmp_path / 'cam.mcap'), TOPIC
    # fixed rate on a virtual clock: the backends take no time, so nothing is dropped
    rate = Rate('fixed', hz=30.0) if mode == 'fixed rate' else Rate('max')
    outcome = run_benchmark(
        RunConfig(
            inputs=[bag], backends=['boom', 'null'], out_dir=tmp_path / 'run', rate=rate, warmup=0
        ),
        clock=VirtualClock() if mode == 'fixed rate' else None,
        backend_factory=_factory,
    )
    assert outcome.run_dir is not None
    run = json.loads((outcome.run_dir / 'run.json').read_text())
    assert outcome.status == run['status'] == 'partial'
    if mode == 'max read ahead':
        assert run['backends'][1]['read_ahead'][0]['used'] is True
    boom, null = run['backends']
    assert boom['status'] == 'failed'
    assert boom['error'] == {
        'input': 0,
        'topic': topic,
        'seq': 5,
        'message': 'RuntimeError: boom at 5',
    }
    assert null['status'] == 'ok'
    assert null['error'] is None
    rows = _rows(outcome.run_dir)
    assert [int(r['seq']) for r in rows if r['backend'] == 'boom'] == [0, 1, 2, 3, 4]
    assert [int(r['seq']) for r in rows if r['backend'] == 'null'] == list(range(20))
    assert run['counts']['frames'] == len(rows) == 25
    measured = {s['backend']: s['measured'] for s in run['summary']}
    assert measured == {'boom': 5, 'null': 20}
    with (outcome.run_dir / 'outputs.mcap').open('rb') as f:
        channels = [ch.topic for _, ch, _ in make_reader(f).iter_messages()]
    assert sum('/replaybench/boom/' in c for c in channels) == 5
    assert sum('/replaybench/null/' in c for c in channels) == 20
    assert (outcome.run_dir / 'report.html').is_file()
    assert 'partial' in (outcome.run_dir / 'report.html').read_text()


# -- order of work ------------------------------------------------------------------------------


# the inputs are hashed while the models load, and a model that cannot load stops the
# hashing at once: tests/replay/test_input_hashing.py


_RENAMES: list[tuple[str, str]] = []
_WATCHING: list[bool] = []


def _audit(event: str, args: tuple[Any, ...]) -> None:
    if _WATCHING and event == 'os.rename':
        _RENAMES.append((str(args[0]), str(args[1])))


sys.addaudithook(_audit)


def test_run_json_is_written_last_after_the_report_and_the_folder_is_swapped_in_after_it(
    tmp_path: Path,
) -> None:
    bag = _bag(tmp_path / 'cam.mcap', n=3)
    out = tmp_path / 'run'
    _RENAMES.clear()
    _WATCHING.append(True)
    try:
        run_benchmark(RunConfig(inputs=[bag], backends=['null'], out_dir=out))
    finally:
        _WATCHING.clear()
    names = [Path(dst).name for _, dst in _RENAMES]
    assert names[-2:] == ['run.json', 'run']
    assert names.index('report.html') < names.index('run.json')
    assert {'frames.csv', 'outputs.mcap', 'summary.csv'} <= set(names[:-2])
    assert Path(_RENAMES[-1][1]) == out
    assert Path(_RENAMES[-1][0]).name.startswith('.run.tmp-')


def test_a_ctrl_c_between_the_two_renames_of_the_swap_puts_the_previous_run_back(
    tmp_path, monkeypatch
):
    import signal

    from replaybench.results.runfolder import RunFolder

    out = tmp_path / 'run'
    out.mkdir()
    (out / 'run.json').write_text('{"previous": true}', encoding='utf-8')
    (out / 'frames.csv').write_text('old', encoding='utf-8')
    handlers = (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM))
    real = Path.rename

    def interrupted(self, target):
        if Path(target) == out and self.name.startswith('.run.tmp-'):
            raise KeyboardInterrupt
        return real(self, target)

    with RunFolder(out, force=True) as folder:
        (folder.path / 'run.json').write_text('{"new": true}', encoding='utf-8')
        monkeypatch.setattr(Path, 'rename', interrupted)
        with pytest.raises(KeyboardInterrupt):
            folder.commit()
        monkeypatch.undo()
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers
    assert (out / 'run.json').read_text(encoding='utf-8') == '{"previous": true}'
    assert (out / 'frames.csv').read_text(encoding='utf-8') == 'old'
    assert sorted(p.name for p in tmp_path.iterdir()) == ['run']


# -- peak: the same folder life cycle ------------------------------------------------------------


def test_a_forced_peak_sweep_that_fails_leaves_the_previous_peak_folder_byte_for_byte(tmp_path):
    from replaybench.app.peak import find_peak_rate

    bag = _bag(tmp_path / 'cam.mcap', n=12)
    out = tmp_path / 'peak'
    sweep: dict[str, Any] = {'trial_frames': 10, 'min_hz': 50.0, 'max_hz': 100.0, 'refine_steps': 0}
    find_peak_rate(bag, 'null', out, options=BackendOptions(), **sweep)
    assert (out / 'peak.json').is_file()
    before = _snapshot(out)
    with pytest.raises(BackendFailedError, match='boom at 5'):
        find_peak_rate(
            bag,
            'boom',
            out,
            options=BackendOptions(),
            force=True,
            backend_factory=_factory,
            **sweep,
        )
    assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['cam.mcap', 'peak']
