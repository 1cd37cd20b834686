"""``--threads``: thread limits for OpenCV and the native thread pools, restored afterwards.

Nothing here writes ``os.environ``: variables such as ``OMP_NUM_THREADS`` are read by a
library once, when it loads, so setting them inside a running process changes nothing for the
libraries already loaded and everything for the caller's later ones. Instead the limits are
set through the libraries themselves and put back when the block ends:

* OpenCV: ``cv2.setNumThreads``;
* the BLAS and OpenMP pools loaded in this process (OpenBLAS, MKL, BLIS, libgomp / libomp):
  ``threadpoolctl.threadpool_limits``;
* onnxruntime takes its intra-op threads from ``SessionOptions`` (``BackendOptions.threads``,
  the ``onnx-cpu`` backend), not from here.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

from replaybench._environ import kept_environ

if TYPE_CHECKING:
    from collections.abc import Iterator

__all__ = ['thread_limits']


@contextlib.contextmanager
def thread_limits(threads: int | None) -> Iterator[None]:
    """At most ``threads`` threads in OpenCV and the native thread pools inside the block; the
    previous settings are restored when it ends, however it ends. ``None``: nothing changes."""
    if threads is None:
        yield
        return
    with kept_environ():  # threadpoolctl sets KMP_DUPLICATE_LIB_OK when it loads
        import cv2
        from threadpoolctl import threadpool_limits

    before = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    try:
        with threadpool_limits(limits=threads):
            yield
    finally:
        cv2.setNumThreads(before)
