"""Output sinks: the detections MCAP written next to the run results."""

from __future__ import annotations

from replaybench.sinks.annotations import annotations_channel, serialize_image_annotations
from replaybench.sinks.mcap_writer import DetectionsWriter, detections_channel, ros1_to_ros2_cdr
from replaybench.sinks.rosbag2 import write_rosbag2_metadata

__all__ = [
    'DetectionsWriter',
    'annotations_channel',
    'detections_channel',
    'ros1_to_ros2_cdr',
    'serialize_image_annotations',
    'write_rosbag2_metadata',
]
