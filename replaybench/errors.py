"""The few error classes of replaybench.

Every error the CLI turns into one line on stderr derives from ``ReplaybenchError``;
``exit_code`` is the process exit status the CLI uses for it.
"""

from __future__ import annotations

__all__ = [
    'BackendError',
    'BackendFailedError',
    'BackendUnavailableError',
    'DecodeError',
    'EngineError',
    'MissingDependencyError',
    'OutputError',
    'ReplaybenchError',
    'RunAborted',
    'SourceError',
    'StereoError',
    'TaskUnavailableError',
    'UsageError',
    'one_line',
]


class ReplaybenchError(Exception):
    """Base of all replaybench errors."""

    exit_code = 2


class UsageError(ReplaybenchError):
    """Bad options or arguments."""


class SourceError(ReplaybenchError):
    """A container that cannot be opened or read at all."""


class StereoError(ReplaybenchError):
    """A stereo pair that cannot be used: images of different sizes, a missing CameraInfo,
    a projection without a baseline, a ``--stereo`` that names no pair."""


class DecodeError(ReplaybenchError):
    """One message that cannot be decoded; the replay skips it and counts it."""


class BackendError(ReplaybenchError):
    """A backend that cannot be configured or fails while running."""


class BackendUnavailableError(BackendError):
    """A backend whose hardware or libraries are missing on this machine."""


class BackendFailedError(BackendError):
    """A backend that raised while detecting, with no other backend left to finish the run."""

    exit_code = 1


class TaskUnavailableError(ReplaybenchError):
    """A task type whose module or entry point cannot be loaded, or is no task."""


class OutputError(ReplaybenchError):
    """An output that cannot be written: disk full, file too large, an I/O error."""

    exit_code = 1


class MissingDependencyError(ReplaybenchError, ImportError):
    """An optional package a feature needs is not installed; the message names the extra."""


class EngineError(ReplaybenchError):
    """The distributed engine (Ray) of a sweep cannot be started or joined."""

    exit_code = 1


class RunAborted(BaseException):
    """A second Ctrl-C or SIGTERM during a run: it stops at once, its outputs unfinished.

    Not a ``ReplaybenchError`` (nor an ``Exception``): like ``KeyboardInterrupt`` it is a
    request to stop, not a failure, and no ``except Exception`` should swallow it.
    """


def one_line(err: BaseException) -> str:
    """``err`` as one line, ``TypeName: first line of its message``: how a plugin's own
    exception is named in an error, a warning or run.json."""
    return f'{type(err).__name__}: {err}'.splitlines()[0]
