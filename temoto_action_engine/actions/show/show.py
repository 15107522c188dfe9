"""show: put any topic on the operator's screen through the Output Manager, until stopped."""
import time

import rospy

from temoto_action_engine.action_base import ActionBase, ActionError

# ROS message type -> Output Manager display type.
DISPLAY_TYPES = {
    'sensor_msgs/PointCloud2': 'point cloud',
    'sensor_msgs/LaserScan': 'laser scan',
    'sensor_msgs/Image': 'image',
    'visualization_msgs/Marker': 'marker',
    'visualization_msgs/MarkerArray': 'marker array',
    'geometry_msgs/PoseStamped': 'pose',
    'nav_msgs/Path': 'path',
    'nav_msgs/Odometry': 'odometry',
}


class Show(ActionBase):
    def display_type_of(self, topic: str) -> str:
        """The display for ``topic``, from its message type at the master (waits a bounded time)."""
        deadline = time.monotonic() + float(self.config.get('topic_wait_s', 5.0))
        while True:
            types = dict(rospy.get_published_topics())
            if topic in types:
                if types[topic] not in DISPLAY_TYPES:
                    raise ActionError('cannot show %s: its type %s has no display (supported: %s)'
                                      % (topic, types[topic], ', '.join(sorted(DISPLAY_TYPES))))
                return DISPLAY_TYPES[types[topic]]
            if time.monotonic() >= deadline or not self.wait(0.25):
                raise ActionError('cannot show %s: nobody publishes it (give display_type to show it anyway)'
                                  % topic)

    def on_start(self):
        topic = self.input('topic')
        display = self.input('display_type') or self.display_type_of(topic)
        self.display_id = self.output_manager.show_in_rviz(display, topic)
        self.set_output('topic', topic)
        self.event('showing', topic=topic, display_type=display)
        self.feedback('showing %s as %s' % (topic, display))
