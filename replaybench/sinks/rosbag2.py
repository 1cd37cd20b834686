"""rosbag2 bag information for an MCAP: the ``rosbag2`` metadata record and ``metadata.yaml``.

rosbag2's MCAP storage stores the bag's information (``BagMetadata``) as YAML under the key
``serialized_metadata`` of a metadata record named ``rosbag2``; a rosbag2 directory holds the
same information in ``metadata.yaml`` under ``rosbag2_bagfile_information``. Both are written
here in metadata version 8 (the version rosbags writes and rosbag2 reads with integer QoS
policies), so that ``ros2 bag info``/``play`` and rosbags' readers take the file as a bag.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

__all__ = ['VERSION', 'bag_information', 'serialized_metadata', 'write_rosbag2_metadata']

#: rosbag2 metadata version written.
VERSION = 8

#: One topic: name, ROS 2 type, message count, offered QoS profiles (YAML), RIHS01 type hash.
Topic = tuple[str, str, int, str, str]


def bag_information(
    file_name: str, topics: Sequence[Topic], start_ns: int, end_ns: int
) -> dict[str, Any]:
    """The rosbag2 ``BagMetadata`` of one MCAP file holding ``topics`` (uncompressed, CDR)."""
    count = sum(topic[2] for topic in topics)
    duration = max(0, end_ns - start_ns) if count else 0
    start = start_ns if count else 0
    return {
        'version': VERSION,
        'storage_identifier': 'mcap',
        'relative_file_paths': [file_name],
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {
                'topic_metadata': {
                    'name': name,
                    'type': msgtype,
                    'serialization_format': 'cdr',
                    'offered_qos_profiles': qos,
                    'type_description_hash': type_hash,
                },
                'message_count': n,
            }
            for name, msgtype, n, qos, type_hash in topics
        ],
        'compression_format': '',
        'compression_mode': '',
        'files': [
            {
                'path': file_name,
                'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': duration},
                'message_count': count,
            }
        ],
        'custom_data': {},
        'ros_distro': '',
    }


def _dump(data: dict[str, Any]) -> str:
    from io import StringIO

    from ruamel.yaml import YAML

    yaml = YAML(typ='safe')
    yaml.default_flow_style = False
    out = StringIO()
    yaml.dump(data, out)
    return out.getvalue()


def serialized_metadata(info: dict[str, Any]) -> str:
    """``info`` as the ``serialized_metadata`` of the ``rosbag2`` metadata record."""
    return _dump(info).strip()


def write_rosbag2_metadata(mcap_path: Path) -> Path:
    """Write ``metadata.yaml`` beside a ROS 2 MCAP, making its folder a rosbag2 bag.

    The topics, counts and times are the MCAP's summary (Statistics), the QoS profiles and type
    hashes its channels' metadata. Returns the path written. Raises ``ValueError`` for an MCAP
    without a summary or with a channel that is not CDR.
    """
    from mcap.reader import make_reader

    with mcap_path.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    if summary is None or summary.statistics is None:
        msg = f'{mcap_path}: no summary with statistics'
        raise ValueError(msg)
    stats = summary.statistics
    topics: list[Topic] = []
    for channel_id in sorted(summary.channels):
        channel = summary.channels[channel_id]
        if channel.message_encoding != 'cdr':
            msg = f'{mcap_path}: channel {channel.topic} is {channel.message_encoding}, not cdr'
            raise ValueError(msg)
        schema = summary.schemas[channel.schema_id]
        topics.append(
            (
                channel.topic,
                schema.name,
                stats.channel_message_counts.get(channel_id, 0),
                channel.metadata.get('offered_qos_profiles', ''),
                channel.metadata.get('topic_type_hash', ''),
            )
        )
    info = bag_information(mcap_path.name, topics, stats.message_start_time, stats.message_end_time)
    path = mcap_path.with_name('metadata.yaml')
    path.write_text(_dump({'rosbag2_bagfile_information': info}))
    return path
