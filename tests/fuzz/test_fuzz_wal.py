"""rosbag2 .db3 files in WAL mode in every state a killed recorder can leave them.

A recorder's connection inserts frames (one commit each), checkpoints (PASSIVE, FULL, RESTART,
TRUNCATE) while other readers pin older snapshots or not; the files are copied while it is
still open, with or without the -shm, with or without metadata.yaml, sometimes with the log cut
mid-write, in a folder whose files (and sometimes the folder itself) are read-only. Property:
the frames replayed are exactly the rows sqlite returns when it opens a copy of the files
normally (``walbags.sqlite_rows``), and the input files stay byte-identical.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from fuzz.fuzzkit import cleanup, fuzz_settings, replay, write_case
from hypothesis import example, given
from hypothesis import strategies as st
from walbags import CAMERA, Step, image_payloads, sqlite_rows, write_wal_bag

STEPS = st.one_of(
    st.builds(Step, st.just('insert'), st.integers(1, 6)),
    st.builds(
        Step,
        st.just('checkpoint'),
        st.just(0),
        st.sampled_from(['PASSIVE', 'FULL', 'RESTART', 'TRUNCATE']),
    ),
    st.just(Step('pin')),
    st.just(Step('unpin')),
)


def build_case(tmp_path: Path, steps: list[Step], shm: bool, metadata: bool, cut: float | None):
    """The files a killed recorder left, in a read-only case folder (``write_case``)."""
    scratch = Path(tempfile.mkdtemp(prefix='build', dir=tmp_path))
    folder = write_wal_bag(scratch / 'bag', image_payloads(16, 16, 12), steps, shm=shm,
                           metadata=metadata)  # fmt: skip
    files = {f'bag/{p.name}': p.read_bytes() for p in folder.iterdir()}
    shutil.rmtree(scratch)
    wal = files.get('bag/bag.db3-wal', b'')
    if cut is not None and wal:
        files['bag/bag.db3-wal'] = wal[: int(len(wal) * cut)]  # the last write torn
    return write_case(tmp_path, files) / 'bag'


#: A reader pins a snapshot after 4 frames: the checkpoint copies only those into the .db3.
PARTIAL = [Step('insert', 4), Step('pin'), Step('insert', 5), Step('checkpoint'), Step('insert', 3)]


@fuzz_settings(0.6)
@example(
    steps=PARTIAL, shm=False, metadata=True, bare=False, read_only_folder=True, cut=None, info=True
)
@example(
    steps=[Step('insert', 6), Step('checkpoint', mode='RESTART'), Step('insert', 2)],
    shm=True,
    metadata=False,
    bare=True,
    read_only_folder=False,
    cut=0.9,
    info=False,
)
@given(
    steps=st.lists(STEPS, min_size=1, max_size=8),
    shm=st.booleans(),
    metadata=st.booleans(),
    bare=st.booleans(),
    read_only_folder=st.booleans(),
    cut=st.one_of(st.none(), st.floats(0.0, 1.0)),
    info=st.booleans(),
)
def test_a_killed_recorders_db3_and_log_replay_the_rows_sqlite_returns(
    tmp_path, steps, shm, metadata, bare, read_only_folder, cut, info
):
    folder = build_case(tmp_path, steps, shm, metadata, cut)
    expected = [t for t, _ in sqlite_rows(folder / 'bag.db3')]
    if read_only_folder:
        folder.chmod(0o555)
    try:
        outcome = replay(folder / 'bag.db3' if bare else folder, tmp_path, info=info)
    finally:
        folder.chmod(0o755)
    rows = [r for r in outcome.rows if r['topic'] == CAMERA]
    assert [int(r['log_time_ns']) for r in rows] == expected
    assert outcome.code == (0 if expected else 2), outcome.stderr
    cleanup(folder.parent, outcome.out)
