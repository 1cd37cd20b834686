"""``replaybench.app.peak``: the command line and the API parse into one ``PeakConfig``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from replaybench.app.peak import PeakConfig, peak_config, run_peak
from replaybench.backends.base import BackendOptions
from replaybench.errors import UsageError

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / 'fixtures' / 'bags' / 'rgb8_raw.mcap'


def test_peak_config_holds_the_options_as_the_search_takes_them() -> None:
    config = peak_config(
        BAG,
        backend='null',
        out='somewhere',
        p99_ms=5.0,
        topics='/camera/image_raw',
        threads=2,
        conf=0.3,
        report=False,
        command=['replaybench', 'peak'],
    )
    assert config == PeakConfig(
        input=BAG,
        backend='null',
        out=Path('somewhere'),
        options=BackendOptions(threads=2, conf=0.3),
        topics=('/camera/image_raw',),
        p99_bound_ms=5.0,
        report=False,
        threads=2,
        command=('replaybench', 'peak'),
    )
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.backend = 'hsv'  # type: ignore[misc]


@pytest.mark.parametrize(
    ('options', 'named'),
    [
        ({'max_drop': 1.5}, '--max-drop'),
        ({'p99_ms': 0.0}, '--p99-ms'),
        ({'min_hz': 10.0, 'max_hz': 5.0}, 'the highest rate (5.0) is below the lowest'),
        ({'engine': 'warp'}, 'warp'),
        ({'precision': 'fp8'}, 'fp8'),
        ({'conf': 2.0}, '--conf'),
    ],
)
def test_peak_config_refuses_a_value_out_of_range_before_anything_runs(
    options: dict[str, object], named: str, tmp_path: Path
) -> None:
    with pytest.raises(UsageError, match=r'\S') as caught:
        peak_config(BAG, backend='null', out=tmp_path / 'peak', **options)  # type: ignore[arg-type]
    assert named in str(caught.value)
    assert not (tmp_path / 'peak').exists()


def test_run_peak_without_a_folder_writes_nothing_and_finds_a_rate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    config = peak_config(BAG, backend='null', trial_frames=8, min_hz=5, max_hz=40, refine_steps=1)
    result = run_peak(config)
    assert result.record is not None
    assert result.record.backend == 'null'
    assert result.trials
    assert list(tmp_path.iterdir()) == []
