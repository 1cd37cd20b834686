"""The stereo task: a disparity of the left rectified image per stereo pair (``Disparity``,
``replaybench.stereo.output``), written as a ``stereo_msgs/msg/DisparityImage`` and scored
against ground-truth disparity (docs/stereo.md)."""

#: where a bag holds the left image's true disparity (a 32FC1 Image or a DisparityImage)
DISPARITY_TRUTH_TOPIC = '/ground_truth/disparity'

__all__ = ['DISPARITY_TRUTH_TOPIC']
