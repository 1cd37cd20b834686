"""The null backend: no detections, zero host stage times."""

from __future__ import annotations

import json

import numpy as np

from replaybench.backends import Backend, BackendOptions
from replaybench.backends.null import NullBackend
from replaybench.types import Frame, StageTimes


def test_null_backend_returns_no_detections_and_zero_stage_times() -> None:
    backend = NullBackend(BackendOptions(threads=2))
    assert isinstance(backend, Backend)
    assert NullBackend.available().ok
    backend.open()
    image = np.zeros((4, 6, 3), dtype=np.uint8)
    result = backend.detect(Frame('/t', 0, 0, 0, 'cam', image, 'rgb8', 'rgb8'))
    assert result.detections == ()
    assert result.stages == StageTimes(preprocess_ns=0, infer_ns=0, postprocess_ns=0)
    assert result.stages.h2d_ns is None
    assert result.stages.d2h_ns is None
    json.dumps(backend.info())
    backend.close()
