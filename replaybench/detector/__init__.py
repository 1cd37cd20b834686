"""The device-independent DNN detector pipeline: model spec, preprocessing, decoders, NMS.

``spec`` reads an ONNX model (input, family, preprocessing, classes), ``preprocess`` turns a
frame into the input tensor and a ``Transform`` back to source pixels, ``decoders`` turns the
outputs into Detections. Backends (``onnx-cpu``, GPU ones) add only the inference engine.
"""

from __future__ import annotations

from replaybench.detector.decoders import (
    decode,
    decode_nms,
    decode_yolov5,
    decode_yolov8,
    decode_yolox,
    nms,
    postprocess,
)
from replaybench.detector.labels import COCO80, parse_names, read_labels_file
from replaybench.detector.preprocess import Letterboxer, Transform, boxes_to_source, letterbox
from replaybench.detector.spec import (
    DEFAULT_MODEL,
    FAMILIES,
    ModelSpec,
    Preprocess,
    default_preprocess,
    family_from_shapes,
    load_model_spec,
)

__all__ = [
    'COCO80',
    'DEFAULT_MODEL',
    'FAMILIES',
    'Letterboxer',
    'ModelSpec',
    'Preprocess',
    'Transform',
    'boxes_to_source',
    'decode',
    'decode_nms',
    'decode_yolov5',
    'decode_yolov8',
    'decode_yolox',
    'default_preprocess',
    'family_from_shapes',
    'letterbox',
    'load_model_spec',
    'nms',
    'parse_names',
    'postprocess',
    'read_labels_file',
]
