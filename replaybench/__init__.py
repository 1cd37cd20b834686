"""replaybench: replay camera logs through detectors and measure speed and accuracy."""

from replaybench._version import __version__

__all__ = ['__version__']
