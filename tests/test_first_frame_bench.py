"""benchmarks/first_frame.py: its sparse bags are real MCAPs that replaybench replays, and its
timing reads the first frame of a fresh process (the figures themselves are the benchmark's)."""

from __future__ import annotations

from benchmarks.first_frame import (
    RATIO_MAX,
    TARGET_S,
    child_environment,
    chunk_count,
    time_to_first_frame,
    verdict,
    write_chunk_bag,
    write_sparse_bag,
)
from replaybench.sources import open_source


def test_a_sparse_bag_is_a_readable_mcap_whose_zeros_take_no_disk(tmp_path):
    bag = tmp_path / 'big.mcap'
    frames = write_sparse_bag(bag, 40_000_000)
    assert frames == 40_000_000 // (1920 * 1080 * 3)
    size = bag.stat().st_size
    assert size > frames * 1920 * 1080 * 3
    assert bag.stat().st_blocks * 512 < size // 4  # holes, not written zeros
    with open_source(bag) as source:
        counts = {t.name: t.count for t in source.topics()}
        assert counts == {'/camera/image_raw': frames, '/camera/camera_info': frames}
        (topic,) = [t for t in source.topics() if t.name == '/camera/image_raw']
        first = next(iter(source.messages(topics=[topic.name])))
        assert first.topic == '/camera/image_raw'


def test_the_first_frame_is_timed_from_a_fresh_process(tmp_path):
    bag = tmp_path / 'bag.mcap'
    write_sparse_bag(bag, 20_000_000)
    first, total = time_to_first_frame(bag, tmp_path / 'run', hash_inputs=True)
    assert 0 < first < total
    assert (tmp_path / 'run' / 'run.json').is_file()


def test_the_timed_runs_keep_their_bytecode_in_a_folder_of_their_own(tmp_path):
    bag = tmp_path / 'bag.mcap'
    write_sparse_bag(bag, 20_000_000)
    env = child_environment(tmp_path / 'pycache')
    assert 'PYTHONDONTWRITEBYTECODE' not in env
    time_to_first_frame(bag, tmp_path / 'run', hash_inputs=False, env=env)
    cached = {p.name.split('.')[0] for p in (tmp_path / 'pycache').rglob('*.pyc')}
    assert {'runner', 'null', 'camera_info'} <= cached


def test_a_chunk_bag_holds_the_chunks_asked_for_each_with_a_frame_and_its_camera_info(tmp_path):
    bag = tmp_path / 'chunks.mcap'
    frames = write_chunk_bag(bag, 300)
    assert chunk_count(bag) == 300
    with open_source(bag) as source:
        counts = {t.name: t.count for t in source.topics()}
        assert counts == {'/camera/image_raw': frames, '/camera/camera_info': frames}


def test_the_verdict_holds_every_bag_to_the_target_and_to_the_first_bags_figure():
    def row(bag: str, first: float) -> dict[str, object]:
        return {'bag': bag, 'first_frame_s': first}

    base = TARGET_S * 0.8
    assert verdict([row('a', base), row('b', base * RATIO_MAX * 0.99)]) == (True, [])
    met, missed = verdict([row('a', base), row('b', base * RATIO_MAX * 1.01)])
    assert not met
    assert len(missed) == 1
    assert missed[0].startswith('b: ')
    met, missed = verdict([row('a', TARGET_S * 1.01)])
    assert not met
    assert missed == [f'a: {TARGET_S * 1.01:.3f} s > {TARGET_S} s']
