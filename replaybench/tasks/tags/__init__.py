"""AprilTags with pose scored against tag ground truth (``replaybench.fiducials``,
``replaybench.results.tags``); the task is ``replaybench.tasks.tags.task``."""
