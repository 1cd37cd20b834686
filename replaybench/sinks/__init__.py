"""Output sinks: the detections MCAP written next to the run results."""

from __future__ import annotations

from replaybench.sinks.mcap_writer import DetectionsWriter, detections_channel

__all__ = ['DetectionsWriter', 'detections_channel']
