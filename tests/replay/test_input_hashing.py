"""Inputs are hashed when nothing is timed: a small one before the replay, a large one after
the passes, so the first frame does not wait for the sha256 and no digest runs beside a
measured frame.

The hash objects here are injected (``run_benchmark(hasher=...)``) and log what they do next to
what the backend does, so the order of events is asserted, never a duration.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

from replaybench.backends.null import NullBackend
from replaybench.errors import BackendError
from replaybench.replay import Rate
from replaybench.replay.hashing import InputHash, describe_size
from replaybench.replay.runner import RunConfig, run_benchmark

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from replaybench.backends.base import BackendOptions
    from replaybench.types import BackendResult, Frame

REPO = Path(__file__).resolve().parents[2]
RAW = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'
EXPECTED = hashlib.sha256(RAW.read_bytes()).hexdigest()
WAIT_S = 30  # an upper bound for events that must come: a hang fails instead of blocking


class _FirstFrame(NullBackend):
    """The null backend, setting ``seen`` when it processes its first frame."""

    def __init__(self, seen: threading.Event) -> None:
        super().__init__()
        self.seen = seen

    def detect(self, frame: Frame) -> BackendResult:
        self.seen.set()
        return super().detect(frame)


class _WaitingDigest:
    """sha256 whose first update waits for ``event``; records whether it came."""

    def __init__(self, event: threading.Event, log: list[str]) -> None:
        self.event = event
        self.log = log
        self.inner = hashlib.sha256()

    def update(self, data: bytes, /) -> None:
        if not self.log:
            self.log.append('came' if self.event.wait(WAIT_S) else 'timed out')
        self.inner.update(data)

    def hexdigest(self) -> str:
        self.log.append('digested')
        return self.inner.hexdigest()


def _background(digest: Callable[[], Any]) -> Callable[[Sequence[Path]], InputHash]:
    """Hash objects that always use a thread (even for the small fixture), in 64 KiB chunks."""

    def make(files: Sequence[Path]) -> InputHash:
        return InputHash(files, digest=digest, inline_max_bytes=0, chunk_bytes=1 << 16)

    return make


def _factory(backend: NullBackend) -> Callable[[str, BackendOptions], NullBackend]:
    return lambda name, options: backend


def _run_json(out: Path) -> dict[str, Any]:
    found: dict[str, Any] = json.loads((out / 'run.json').read_text(encoding='utf-8'))
    return found


class _LoggingDigest:
    """sha256 that logs its updates into a shared log."""

    def __init__(self, log: list[str]) -> None:
        self.log = log
        self.inner = hashlib.sha256()

    def update(self, data: bytes, /) -> None:
        self.log.append('digest')
        self.inner.update(data)

    def hexdigest(self) -> str:
        return self.inner.hexdigest()


class _LoggingNull(NullBackend):
    def __init__(self, log: list[str]) -> None:
        super().__init__()
        self.log = log

    def detect(self, frame: Frame) -> BackendResult:
        self.log.append('frame')
        return super().detect(frame)


def test_a_large_input_is_hashed_after_the_passes_never_beside_a_measured_frame(tmp_path):
    log: list[str] = []
    out = tmp_path / 'run'
    run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=out, report=False, repeat=2),
        backend_factory=_factory(_LoggingNull(log)),
        hasher=_background(lambda: _LoggingDigest(log)),
    )
    first_digest = log.index('digest')
    assert log[:first_digest] == ['frame'] * first_digest  # every frame, then the hash
    assert 'frame' not in log[first_digest:]
    assert first_digest == 2 * 10  # both passes over the 10 frames came first
    (entry,) = _run_json(out)['inputs']
    assert entry['sha256'] == EXPECTED
    assert not any('sha256' in w for w in entry['warnings'])


def test_an_input_that_changes_during_the_run_gets_no_sha256_and_a_warning(tmp_path):
    bag = tmp_path / 'cam.mcap'
    bag.write_bytes(RAW.read_bytes())

    class Touching(NullBackend):
        def detect(self, frame: Frame) -> BackendResult:
            os.utime(bag, ns=(1, 1))  # as a copy still being written would
            return super().detect(frame)

    out = tmp_path / 'run'
    run_benchmark(
        RunConfig(inputs=[bag], backends=['null'], out_dir=out, report=False),
        backend_factory=_factory(Touching()),
        hasher=_background(hashlib.sha256),
    )
    (entry,) = _run_json(out)['inputs']
    assert entry['sha256'] is None
    assert any('changed during the run' in w for w in entry['warnings'])


def test_a_small_input_is_hashed_after_the_passes_too_and_its_run_has_no_hashing_warning(
    tmp_path,
):
    log: list[str] = []
    out = tmp_path / 'run'
    run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=out, report=False),
        backend_factory=_factory(_LoggingNull(log)),
        hasher=lambda files: InputHash(files, digest=lambda: _LoggingDigest(log)),
    )
    assert log.index('digest') > max(i for i, e in enumerate(log) if e == 'frame')
    (entry,) = _run_json(out)['inputs']
    assert entry['sha256'] == EXPECTED
    assert not [w for w in entry['warnings'] if 'sha256' in w]


def test_no_hash_records_a_null_sha256_and_says_so_without_reading_the_input(tmp_path):
    def refuse(_files: Sequence[Path]) -> InputHash:
        msg = 'hashed although hash_inputs is False'
        raise AssertionError(msg)

    out = tmp_path / 'run'
    run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=out, report=False, hash_inputs=False),
        hasher=refuse,
    )
    (entry,) = _run_json(out)['inputs']
    assert entry['sha256'] is None
    assert any('--no-hash' in w and 'sha256' in w for w in entry['warnings'])


def test_a_known_sha256_is_recorded_without_hashing_the_input_again(tmp_path):
    def refuse(_files: Sequence[Path]) -> InputHash:
        msg = 'hashed although the sha256 was given'
        raise AssertionError(msg)

    out = tmp_path / 'run'
    run_benchmark(
        RunConfig(
            inputs=[RAW], backends=['null'], out_dir=out, report=False, input_sha256=('ab' * 32,)
        ),
        hasher=refuse,
    )
    assert _run_json(out)['inputs'][0]['sha256'] == 'ab' * 32


def test_an_input_over_a_gigabyte_is_announced_naming_sha256(tmp_path):
    class Large(InputHash):
        def __init__(self, files: Sequence[Path]) -> None:
            super().__init__(files)
            self.size_bytes = 12_000_000_000
            self.background = True

    lines: list[str] = []
    run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=tmp_path / 'run', report=False),
        hasher=Large,
        notice=lines.append,
    )
    assert lines == ['replaybench: hashing rgb8_raw.mcap (12.0 GB, sha256) after the passes']


def test_a_small_input_is_not_announced(tmp_path):
    lines: list[str] = []
    run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=tmp_path / 'run', report=False),
        notice=lines.append,
    )
    assert lines == []


def test_a_model_that_cannot_load_leaves_nothing_and_a_large_input_unhashed(tmp_path):
    made: list[InputHash] = []

    def hasher(files: Sequence[Path]) -> InputHash:
        made.append(InputHash(files, inline_max_bytes=0))
        return made[-1]

    class Broken(NullBackend):
        def open(self) -> None:
            msg = 'cannot load the model'
            raise RuntimeError(msg)

    with pytest.raises(BackendError, match='cannot load the model'):
        run_benchmark(
            RunConfig(inputs=[RAW], backends=['null'], out_dir=tmp_path / 'run'),
            backend_factory=_factory(Broken()),
            hasher=hasher,
        )
    (hashing,) = made
    assert hashing.started_s is None  # left for after the passes, which never came
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_an_interrupted_run_does_not_wait_for_the_hash_and_records_none(tmp_path):
    stop, released = threading.Event(), threading.Event()

    class Held(InputHash):
        def request_cancel(self) -> None:
            super().request_cancel()
            released.set()

    class Digest:
        def update(self, data: bytes, /) -> None:
            released.wait(WAIT_S)

        def hexdigest(self) -> str:
            return '00' * 32

    class Stopping(NullBackend):
        def detect(self, frame: Frame) -> BackendResult:
            stop.set()  # as Ctrl-C does through the command line's signal handler
            return super().detect(frame)

    out = tmp_path / 'run'
    outcome = run_benchmark(
        # a timed replay looks at the token before each frame it releases
        RunConfig(
            inputs=[RAW],
            backends=['null'],
            out_dir=out,
            report=False,
            rate=Rate('fixed', hz=1000.0),
        ),
        backend_factory=_factory(Stopping()),
        stop=stop,
        hasher=lambda files: Held(files, digest=Digest, inline_max_bytes=0, chunk_bytes=1 << 16),
    )
    assert outcome.status == 'interrupted'
    (entry,) = _run_json(out)['inputs']
    assert entry['sha256'] is None
    assert any('interrupted' in w and 'sha256' in w for w in entry['warnings'])


def test_an_unreadable_file_gives_no_digest_and_says_why(tmp_path):
    gone = tmp_path / 'gone.mcap'
    gone.write_bytes(b'x' * 10)
    hashing = InputHash([gone], inline_max_bytes=0)
    gone.unlink()
    assert hashing.start().wait() is None
    assert hashing.error is not None
    assert 'gone.mcap' in hashing.error


def test_a_background_hash_equals_hashlib_over_the_files_in_order(tmp_path):
    a, b = tmp_path / 'a.db3', tmp_path / 'b.db3'
    a.write_bytes(b'first' * 1000)
    b.write_bytes(b'second' * 1000)
    hashing = InputHash([a, b], inline_max_bytes=0, chunk_bytes=100).start()
    assert hashing.background
    assert hashing.wait() == hashlib.sha256(a.read_bytes() + b.read_bytes()).hexdigest()


@pytest.mark.parametrize(
    ('size', 'text'),
    [(12_000_000_000, '12.0 GB'), (712_300_000, '712.3 MB'), (2_048, '2.0 kB'), (5, '5 B')],
)
def test_sizes_are_described_in_decimal_units(size, text):
    assert describe_size(size) == text


def test_a_peak_search_hashes_its_input_once_and_every_trial_records_the_sha256(
    tmp_path, monkeypatch
):
    from replaybench.backends.base import BackendOptions
    from replaybench.replay import VirtualClock
    from replaybench.replay import inputs as inputs_module
    from replaybench.replay.peak import find_peak_rate

    made: list[InputHash] = []

    class Counted(InputHash):
        def __init__(self, files: Sequence[Path]) -> None:
            super().__init__(files)
            made.append(self)

    monkeypatch.setattr(inputs_module, 'InputHash', Counted)
    out = tmp_path / 'peak'
    result = find_peak_rate(
        RAW,
        'null',
        out,
        options=BackendOptions(),
        clock=VirtualClock(),
        max_hz=40.0,
        refine_steps=0,
        report=False,
    )
    trials = sorted(out.rglob('run.json'))
    assert len(trials) == len(result.trials) + 1 >= 3  # the max-rate probe and the trials
    assert {_run_json(t.parent)['inputs'][0]['sha256'] for t in trials} == {EXPECTED}
    assert len(made) == 1  # the probe's; the trials reuse it
    assert json.loads((out / 'peak.json').read_text(encoding='utf-8'))['input']['sha256'] == (
        EXPECTED
    )


def test_a_backend_still_opening_after_two_seconds_is_announced(tmp_path, monkeypatch):
    from replaybench.replay import sessions

    monkeypatch.setattr(sessions, 'SLOW_OPEN_S', 0.01)
    announced = threading.Event()
    lines: list[str] = []

    def notice(line: str) -> None:
        lines.append(line)
        announced.set()

    class Slow(NullBackend):
        def open(self) -> None:
            # a model conversion or an engine build: it lasts until the line has been shown
            assert announced.wait(WAIT_S)

    run_benchmark(
        RunConfig(inputs=[RAW], backends=['null'], out_dir=tmp_path / 'run', report=False),
        backend_factory=_factory(Slow()),
        notice=notice,
    )
    assert len(lines) == 1
    assert lines[0].startswith('replaybench: opening backend null (loading its model')
