"""Segmentation masks scored against ground-truth label images (``replaybench.segmentation``,
``replaybench.results.segmentation``); the task is ``replaybench.tasks.segmentation.task``."""
