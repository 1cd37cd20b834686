"""The bundled segmentation model (training/train_seg.py) through onnx-seg on held-out frames."""

from __future__ import annotations

import numpy as np

from replaybench.backends.base import BackendOptions
from replaybench.backends.onnx_seg import OnnxSegBackend
from replaybench.fixtures.masks import MASK_CLASS_NAMES, semantic_labels
from replaybench.fixtures.scene import DEFAULT_SEED, Scene
from replaybench.segmentation.spec import DEFAULT_SEG_MODEL
from replaybench.tasks.segmentation.scoring import confusion, scores
from replaybench.types import Frame


def test_the_bundled_model_is_small_and_describes_itself() -> None:
    assert DEFAULT_SEG_MODEL.is_file()
    assert DEFAULT_SEG_MODEL.stat().st_size < 300_000
    backend = OnnxSegBackend(BackendOptions(threads=1))
    backend.open()
    info = backend.info()
    assert info['class_names'] == list(MASK_CLASS_NAMES)
    assert (info['layout'], info['layout_source']) == ('logits-nchw', 'metadata')
    assert info['input_size'] == [320, 240]
    assert info['preprocess']['letterbox'] is False


def test_the_bundled_model_labels_held_out_fixture_frames_well() -> None:
    # the fixture seed is outside the training seeds (training/train_seg.py)
    backend = OnnxSegBackend(BackendOptions(threads=1))
    scene = Scene((320, 240), 0, DEFAULT_SEED)
    total = np.zeros((256, 256), dtype=np.int64)
    for index in range(0, 30, 3):
        image, _ = scene.render(index)
        frame = Frame('/camera/image_raw', index, 0, 0, 'cam', image, 'bgr8', 'bgr8')
        mask = backend.detect(frame).mask
        assert mask is not None
        assert mask.labels.shape == (240, 320)
        total += confusion(mask.labels, semantic_labels(scene, index))
    result = scores(total)
    assert result.miou is not None
    assert result.miou > 0.85
    assert set(result.iou) == set(range(len(MASK_CLASS_NAMES)))
