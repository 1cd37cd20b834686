"""Segmentation masks scored against ground-truth label images (``replaybench.segmentation``,
``replaybench.tasks.segmentation.scoring``); the task is ``replaybench.tasks.segmentation.task``."""
