"""A third-party task for replaybench: an image's mean grey level (``brightness``)."""

#: where the bag holds the truth: one ``sensor_msgs/msg/Illuminance`` per frame, its header the
#: frame's, its ``illuminance`` the frame's mean grey level
TRUTH_TOPIC = '/ground_truth/brightness'
#: the type of the truth and of the outputs written into outputs.mcap
MSGTYPE = 'sensor_msgs/msg/Illuminance'

__all__ = ['MSGTYPE', 'TRUTH_TOPIC']
