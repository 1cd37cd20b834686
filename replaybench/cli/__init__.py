"""The ``replaybench`` command line: a thin layer over the library.

Each command lives in its own module and registers itself on ``app`` when imported: it parses
its options into the application's config object, calls the application (``replaybench.app``)
and prints what it returned; a ``ReplaybenchError`` becomes one line on stderr and its exit
status (``replaybench.cli._common.fail``).
"""

from __future__ import annotations

import importlib
import sys

from replaybench.cli._common import EXIT_INTERRUPTED, app
from replaybench.errors import RunAborted

__all__ = ['app', 'main']

#: the command modules; each registers its commands on ``app`` when imported, and
#: ``replaybench --help`` lists them in this order
COMMAND_MODULES = (
    'run',
    'info',
    'backends',
    'fixtures',
    'peak',
    'sweep',
    'compare',
    'report',
    'quantize',
)
for _name in COMMAND_MODULES:
    importlib.import_module(f'replaybench.cli.{_name}')


def main() -> None:
    """Console-script entry point."""
    try:
        app()
    except KeyboardInterrupt:
        sys.stderr.write('replaybench: interrupted\n')
        sys.exit(EXIT_INTERRUPTED)
    except RunAborted:
        sys.stderr.write('replaybench: interrupted again: stopped without finishing the outputs\n')
        sys.exit(EXIT_INTERRUPTED)


if __name__ == '__main__':
    main()
