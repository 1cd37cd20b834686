"""``python -m benchmarks``: thread pools are pinned to one thread before numpy or OpenCV load."""

import sys

from benchmarks.core import pin_thread_env

pin_thread_env()

from benchmarks.suite import main  # noqa: E402 - after pinning the thread pools

sys.exit(main())
