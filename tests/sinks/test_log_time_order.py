"""DetectionsWriter writes in log-time order whatever order the messages come in."""

from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from replaybench import msgs
from replaybench.sinks import DetectionsWriter
from replaybench.types import Detection, RawMessage

T0 = 1_700_000_000_000_000_000
BOX = Detection(0, 'red', 0.5, 1.0, 2.0, 3.0, 4.0)


def _image(topic: str, log_time: int) -> RawMessage:
    data = msgs.serialize_compressed_image(log_time, 'cam', b'\xff\xd8 not decoded', 'jpeg')
    return RawMessage(topic, msgs.COMPRESSED_IMAGE, 'cdr', log_time, 0, data)


def _read(path: Path) -> list[tuple[str, int, int]]:
    """(topic, log time, sequence) of every message in file order."""
    with path.open('rb') as stream:
        reader = make_reader(stream)
        return [
            (c.topic, m.log_time, m.sequence)
            for _, c, m in reader.iter_messages(log_time_order=False)
        ]


def test_passes_written_one_after_the_other_come_out_merged_by_log_time(tmp_path: Path) -> None:
    path = tmp_path / 'detections.mcap'
    with DetectionsWriter(path, annotations=True) as writer:
        for backend in ('hsv', 'null'):  # the runner adds each backend after its pass
            for i in range(3):
                writer.add(backend, '/cam', T0 + i, T0 + i, 'cam', [BOX])
        for i in range(3):  # --copy-images adds the images after every pass
            writer.add_raw(_image('/cam', T0 + i))
    got = _read(path)
    order = [
        '/cam',
        '/replaybench/hsv/cam/detections',
        '/replaybench/null/cam/detections',
        '/replaybench/hsv/cam/annotations',
        '/replaybench/null/cam/annotations',
    ]
    # one log time: the image, then the detections, then the annotations, by backend order
    assert got == [(topic, T0 + i, i) for i in range(3) for topic in order]


@settings(max_examples=40, deadline=None)
@given(
    steps=st.lists(
        st.tuples(st.sampled_from(['hsv', 'null', 'image']), st.integers(0, 6)), max_size=40
    )
)
def test_any_arrival_order_gives_the_same_sorted_file(steps: list[tuple[str, int]]) -> None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / 'detections.mcap'
        rank = {'/cam': 0}
        with DetectionsWriter(path) as writer:
            for kind, t in steps:
                if kind == 'image':
                    writer.add_raw(_image('/cam', T0 + t))
                else:
                    writer.add(kind, '/cam', T0 + t, T0 + t, 'cam', [])
        got = _read(path)
        # channel ids follow first use; ties: the image first, then detections by channel id
        first_use = dict.fromkeys(
            f'/replaybench/{kind}/cam/detections' for kind, _ in steps if kind != 'image'
        )
        rank.update({topic: 1 + i for i, topic in enumerate(first_use)})
        assert len(got) == len(steps)
        assert [(t, rank[topic]) for topic, t, _ in got] == sorted(
            (t, rank[topic]) for topic, t, _ in got
        )
        for topic in rank:
            assert [s for name, _, s in got if name == topic] == list(
                range(sum(name == topic for name, _, _ in got))
            )
        with path.open('rb') as stream:
            summary = make_reader(stream).get_summary()
        assert summary is not None
        assert summary.statistics is not None
        assert summary.statistics.message_count == len(steps)
        if steps:
            times = [T0 + t for _, t in steps]
            assert summary.statistics.message_start_time == min(times)
            assert summary.statistics.message_end_time == max(times)
