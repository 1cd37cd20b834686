"""Tag sizes a bag records of itself: the ``replaybench.tags`` MCAP metadata record.

A bag that knows its tags' edge lengths (the tag fixture writers do) records them in one MCAP
metadata record named ``replaybench.tags`` (``METADATA_NAME``) with the keys ``tag_size`` (the
default edge, m) and ``tag_sizes`` (``ID=M,...``), spelled as ``--tag-size`` and
``--tag-sizes`` take them. When a run is given neither option (nor the keys in ``--config`` or
a sweep parameter), the tag backends use the bag's sizes; otherwise the default
(``DEFAULT_TAG_SIZE``). ROS 1 bags and rosbag2 sqlite3 bags have no MCAP metadata.

The record is found through the MCAP footer, its summary offsets and the metadata index (a few
small reads, however many chunks the file holds), not through the whole summary.
``bag_size_keys`` gives what the run hands to the tag backends (``BAG_SIZE_KEYS`` in
``BackendOptions.tag_options``); ``replaybench.fiducials.detect.tag_options`` decides.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from replaybench.errors import ReplaybenchError
from replaybench.fiducials.pose import parse_tag_sizes

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

__all__ = [
    'BAG_SIZE_KEYS',
    'METADATA_NAME',
    'bag_size_keys',
    'read_mcap_metadata',
    'tag_size_record',
]

METADATA_NAME = 'replaybench.tags'
#: ``BackendOptions.tag_options`` keys the run fills in: the bag's ``tag_size`` and
#: ``tag_sizes``, where they came from (or why there are none), and a conflict between inputs.
BAG_SIZE_KEYS = ('bag_tag_size', 'bag_tag_sizes', 'bag_sizes_from', 'bag_sizes_conflict')

_MAGIC = b'\x89MCAP0\r\n'
_FOOTER = 0x02
_METADATA = 0x0C
_METADATA_INDEX = 0x0D
_SUMMARY_OFFSET = 0x0E


def tag_size_record(default: float, per_id: Mapping[int, float]) -> dict[str, str]:
    """The ``replaybench.tags`` record of a bag whose tags are ``per_id`` (m) and ``default``
    for any other id."""
    sizes = ','.join(f'{k}={v:g}' for k, v in sorted(per_id.items()))
    return {'tag_size': f'{default:g}', 'tag_sizes': sizes}


def _string(data: bytes, at: int) -> tuple[str, int]:
    (n,) = struct.unpack_from('<I', data, at)
    return data[at + 4 : at + 4 + n].decode('utf-8'), at + 4 + n


def _records(data: bytes) -> list[tuple[int, bytes]]:
    out = []
    at = 0
    while at + 9 <= len(data):
        opcode, length = struct.unpack_from('<BQ', data, at)
        out.append((opcode, data[at + 9 : at + 9 + length]))
        at += 9 + length
    return out


def _read(f: BinaryIO, start: int, length: int) -> bytes:
    f.seek(start)
    data = f.read(length)
    if len(data) != length:
        msg = 'truncated'
        raise ValueError(msg)
    return data


def read_mcap_metadata(path: Path, name: str) -> dict[str, str] | None:
    """The first metadata record ``name`` of an MCAP file, None when it has none (or no
    summary to find it by); ``ValueError`` for a file whose footer or index does not parse."""
    with path.open('rb') as f:
        f.seek(0, 2)
        size = f.tell()
        tail = _read(f, size - 37, 37) if size >= 37 + 8 else b''
        if tail[-8:] != _MAGIC or tail[0] != _FOOTER:
            msg = 'no MCAP footer'
            raise ValueError(msg)
        summary_start, offsets_start = struct.unpack_from('<QQ', tail, 9)
        if summary_start == 0:
            return None
        end = size - 37
        if offsets_start:
            groups = _records(_read(f, offsets_start, end - offsets_start))
            index = b''
            for opcode, body in groups:
                if opcode == _SUMMARY_OFFSET and body[0] == _METADATA_INDEX:
                    start, length = struct.unpack_from('<QQ', body, 1)
                    index = _read(f, start, length)
        else:  # no offsets: the summary itself
            index = _read(f, summary_start, end - summary_start)
        for opcode, body in _records(index):
            if opcode != _METADATA_INDEX:
                continue
            offset, length = struct.unpack_from('<QQ', body, 0)
            found, _ = _string(body, 16)
            if found != name:
                continue
            record = _read(f, offset, length)
            opcode, body_length = struct.unpack_from('<BQ', record, 0)
            if opcode != _METADATA:
                msg = 'metadata index points at another record'
                raise ValueError(msg)
            body = record[9 : 9 + body_length]
            _, at = _string(body, 0)
            (map_length,) = struct.unpack_from('<I', body, at)
            at += 4
            stop = at + map_length
            values: dict[str, str] = {}
            while at < stop:
                key, at = _string(body, at)
                value, at = _string(body, at)
                values[key] = value
            return values
    return None


def _mcap_files(path: Path) -> list[Path]:
    """The MCAP files of an input; only regular files (a FIFO or a device is never opened
    here: ``replaybench.sources.open_source`` refuses it with its own line)."""
    if path.is_dir():
        return sorted(p for p in path.glob('*.mcap') if p.is_file())
    return [path] if path.suffix == '.mcap' and path.is_file() else []


def _one(path: Path) -> tuple[tuple[str, str] | None, str]:
    """(tag_size, tag_sizes) an input records and where, or None and why it has none."""
    files = _mcap_files(path)
    if not files:
        return None, f'{path.name} is no MCAP file and so records no tag sizes'
    for file in files:
        try:
            record = read_mcap_metadata(file, METADATA_NAME)
        except (OSError, ValueError, struct.error, UnicodeDecodeError):
            record = None
        if record is None:
            continue
        size, sizes = record.get('tag_size', ''), record.get('tag_sizes', '')
        try:
            parse_tag_sizes(size or None, sizes or None)
        except ReplaybenchError as err:
            return None, f"{file.name}'s {METADATA_NAME} metadata does not parse ({err})"
        return (size, sizes), f"{file.name}'s {METADATA_NAME} metadata"
    return None, f'{path.name} records no tag sizes (no {METADATA_NAME} metadata)'


def bag_size_keys(inputs: Sequence[Path]) -> dict[str, str]:
    """The ``BAG_SIZE_KEYS`` of a run's inputs: the sizes they record (when every input records
    the same ones), where from, or why there are none; ``bag_sizes_conflict`` when inputs
    record different sizes (or some record none), which a run without sizes of its own
    refuses."""
    found = [(p, *_one(Path(p))) for p in inputs]
    sizes = {s for _, s, _ in found}
    if len(sizes) > 1:
        parts = ', '.join(
            f'{Path(p).name}: {"none" if s is None else (s[0] + " m " + s[1]).strip()}'
            for p, s, _ in found
        )
        return {'bag_sizes_conflict': f'the inputs record different tag sizes ({parts})'}
    (only,) = sizes if sizes else (None,)
    where = '; '.join(w for _, _, w in found)
    if only is None:
        return {'bag_sizes_from': where}
    return {'bag_tag_size': only[0], 'bag_tag_sizes': only[1], 'bag_sizes_from': where}
