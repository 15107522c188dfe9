"""show: put any topic on the operator's screen through the Output Manager, until stopped.

The display is requested with this action's own failure policy: when it fails (its RViz host
crashed), it is requested once more (a new host starts); if that fails too, the action ends
FAILED with the reason, so a graph never says it shows something that is not on screen.
"""
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
    'geometry_msgs/PoseArray': 'pose array',
    'geometry_msgs/PointStamped': 'point stamped',
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
        self.topic = self.input('topic')
        self.display = self.input('display_type') or self.display_type_of(self.topic)
        self.display_id = self.output_manager.show_in_rviz(self.display, self.topic, on_status=self.post)
        self.set_output('topic', self.topic)
        self.event('showing', topic=self.topic, display_type=self.display)
        self.feedback('showing %s as %s' % (self.topic, self.display))

    def execute(self):
        while self.action_ok():
            ev = self.next_item(3600.0)
            if ev is None or not self.action_ok() or ev.resource_id != self.display_id or not ev.failed:
                continue
            self.event('display_failed', topic=self.topic, display_type=self.display, message=ev.message)
            try:
                self.output_manager.hide(self.display_id)
            except Exception as e:
                self.log_warn('releasing the failed display: %s' % e)
            try:
                self.display_id = self.output_manager.show_in_rviz(self.display, self.topic, on_status=self.post)
            except Exception as e:
                self.fail('the display of %s failed (%s) and could not be shown again: %s'
                          % (self.topic, ev.message, e))
                return
            self.event('display_restored', topic=self.topic, display_type=self.display)
            self.feedback('the display of %s failed (%s); showing it again' % (self.topic, ev.message))
