"""What the tasks' sinks call on a run's output writer, whichever it is.

Two writers take a run's outputs: outputs.mcap's (``replaybench.sinks.mcap_writer.
DetectionsWriter``) and, for a run kept in memory, ``replaybench.replay.output.Discard``, whose
calls do nothing. Both are an ``OutputWriter``, so a task's sink (``tasks/tags/sink.py``,
``tasks/segmentation/sink.py``) calls the same methods on either and tests neither's type nor its
attributes.
"""

from __future__ import annotations

from typing import Protocol

__all__ = ['OutputWriter']


class OutputWriter(Protocol):
    """A run's output writer as the tasks' sinks see it."""

    @property
    def keeps(self) -> bool:
        """Whether what it is given is kept (False: the in-memory writer, which drops it); a
        sink makes no message that nothing keeps."""
        ...

    @property
    def annotations(self) -> bool:
        """Whether it writes annotations (``--annotations``): pictures and outlines."""
        ...

    @property
    def depth(self) -> bool:
        """Whether it writes depth Images beside disparities (``--depth``)."""
        ...

    def colour(self, backend: str) -> str:
        """The backend's colour in annotations (``#rrggbb``)."""
        ...

    def add_message(
        self,
        topic: str,
        msgtype: str,
        log_time_ns: int,
        data: bytes | memoryview,
        *,
        annotation: bool = False,
    ) -> None:
        """One ROS 2 CDR message of a result channel; ``annotation``: an annotation's."""
        ...

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record ``name`` (string keys and values)."""
        ...
