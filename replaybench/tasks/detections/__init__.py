"""Boxes: every backend's detections, scored against Detection2DArray ground truth
(``replaybench.results.accuracy``); the task is ``replaybench.tasks.detections.task``."""
