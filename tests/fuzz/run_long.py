"""The long hostile-input run: ``python tests/fuzz/run_long.py [pytest options]``.

Same as ``make fuzz`` (``REPLAYBENCH_FUZZ=long pytest tests/fuzz``): thousands of examples per
property, fresh random seeds each run, no deadline. Failures print a ``@reproduce_failure``
blob to replay them.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def main() -> int:
    env = dict(os.environ, REPLAYBENCH_FUZZ='long')
    here = Path(__file__).resolve().parent
    command = [sys.executable, '-m', 'pytest', str(here), '-q', *sys.argv[1:]]
    return subprocess.call(command, env=env, cwd=here.parents[1])


if __name__ == '__main__':
    sys.exit(main())
