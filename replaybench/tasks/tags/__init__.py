"""AprilTags with pose scored against tag ground truth (``replaybench.fiducials``,
``replaybench.tasks.tags.scoring``); the task is ``replaybench.tasks.tags.task``."""

__all__ = ['TAG_GROUND_TRUTH_TOPIC']

#: Where tag ground truth is read from (AprilTagDetectionArray, keyed by frame_id and stamp).
TAG_GROUND_TRUTH_TOPIC = '/ground_truth/tags'
