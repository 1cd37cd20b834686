"""replaybench: replay camera logs through detectors and measure speed and accuracy."""

__version__ = '0.1.0'

__all__ = ['__version__']
