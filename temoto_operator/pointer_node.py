"""The pointer node: keeps the operator's last pointed goal for "Robot please go" (``pointing.py``).

In (RViz's own tools, global names as RViz publishes them):
- ``/move_base_simple/goal`` (``geometry_msgs/PoseStamped``): "2D Nav Goal", a place and a heading;
- ``/clicked_point`` (``geometry_msgs/PointStamped``): "Publish Point", a place; the robot faces it from
  where it stands;
- ``/<ns>/pointed_goal/used`` (``std_msgs/String``, who used it): the goal leaves the scene.

Out, latched:
- ``/<ns>/pointed_goal`` (``PoseStamped``): the goal to use; an empty ``frame_id`` when there is none; an
  orientation of all zeros when it has no heading;
- ``/<ns>/pointed_goal/marker`` (``visualization_msgs/Marker``): the goal in the scene, an arrow or a
  sphere, until it is used or replaced.

A pointed goal that cannot be a goal (no frame, not finite, a tilted heading) is refused with the field
named, in the log and on ``/<ns>/action_engine/feedback``, and the goal before it stays.
Parameters: ``~temoto_namespace`` (default ``temoto``).
"""
from __future__ import annotations

import threading
import time

import rospy
from geometry_msgs.msg import PointStamped, PoseStamped
from std_msgs.msg import ColorRGBA, String
from visualization_msgs.msg import Marker

from temoto_core import params
from temoto_core.node import init_node, spin
from temoto_operator.pointing import NO_HEADING, BadPointing, Pointed, PointedGoal, checked

NODE = 'pointer'


def pose_of(pointed: Pointed | None) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp = rospy.Time.now()
    if pointed is None:
        return msg
    msg.header.frame_id = pointed.frame
    msg.pose.position.x, msg.pose.position.y = pointed.x, pointed.y
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = pointed.quaternion
    return msg


def pointed_of(msg: PoseStamped, source: str = 'pointed_goal') -> Pointed | None:
    """What ``/<ns>/pointed_goal`` carries, as a Pointed; None when nothing is pointed."""
    if not msg.header.frame_id.strip():
        return None
    o, p = msg.pose.orientation, msg.pose.position
    quaternion = (o.x, o.y, o.z, o.w)
    return checked(msg.header.frame_id, (p.x, p.y, p.z), None if quaternion == NO_HEADING else quaternion,
                   source, msg.header.stamp.to_sec())


class PointerNode:
    def __init__(self) -> None:
        ns = params.text('temoto_namespace', 'temoto').strip('/') or 'temoto'
        self.goal = PointedGoal()
        self.lock = threading.Lock()
        self.pub_goal = rospy.Publisher('/%s/pointed_goal' % ns, PoseStamped, queue_size=1, latch=True)
        self.pub_marker = rospy.Publisher('/%s/pointed_goal/marker' % ns, Marker, queue_size=1, latch=True)
        self.pub_feedback = rospy.Publisher('/%s/action_engine/feedback' % ns, String, queue_size=5)
        self.pub_goal.publish(pose_of(None))
        rospy.Subscriber('/move_base_simple/goal', PoseStamped, self._on_nav_goal, queue_size=5)
        rospy.Subscriber('/clicked_point', PointStamped, self._on_clicked_point, queue_size=5)
        rospy.Subscriber('/%s/pointed_goal/used' % ns, String, self._on_used, queue_size=5)
        rospy.loginfo('%s: goals from /move_base_simple/goal and /clicked_point, kept on /%s/pointed_goal', NODE, ns)

    def _on_nav_goal(self, msg: PoseStamped) -> None:
        p, o = msg.pose.position, msg.pose.orientation
        self._point(lambda: checked(msg.header.frame_id, (p.x, p.y, p.z), (o.x, o.y, o.z, o.w), 'nav_goal',
                                    time.time()))

    def _on_clicked_point(self, msg: PointStamped) -> None:
        p = msg.point
        self._point(lambda: checked(msg.header.frame_id, (p.x, p.y, p.z), None, 'clicked_point', time.time()))

    def _point(self, make) -> None:
        try:
            pointed = make()
        except BadPointing as err:
            text = 'pointed goal refused: %s' % err
            rospy.logwarn('%s: %s', NODE, text)
            self.pub_feedback.publish(String(text))
            return
        with self.lock:
            self.goal.point(pointed)
            self.pub_goal.publish(pose_of(pointed))
            self.pub_marker.publish(self._marker(pointed))
        rospy.loginfo('%s: goal pointed %s', NODE, pointed.describe())

    def _on_used(self, msg: String) -> None:
        with self.lock:
            used = self.goal.use(msg.data.strip() or 'someone')
            if used is None:
                return
            self.pub_goal.publish(pose_of(None))
            self.pub_marker.publish(self._marker(None))
        rospy.loginfo('%s: goal %s used by %s', NODE, used.describe(), msg.data.strip() or 'someone')

    @staticmethod
    def _marker(pointed: Pointed | None) -> Marker:
        m = Marker()
        m.ns, m.id = 'pointed_goal', 0
        m.header.stamp = rospy.Time.now()
        if pointed is None:
            m.action = Marker.DELETE
            return m
        m.header.frame_id = pointed.frame
        m.action = Marker.ADD
        m.pose.position.x, m.pose.position.y, m.pose.position.z = pointed.x, pointed.y, 0.05
        if pointed.has_heading:
            m.type = Marker.ARROW
            o = m.pose.orientation
            o.x, o.y, o.z, o.w = pointed.quaternion
            m.scale.x, m.scale.y, m.scale.z = 0.6, 0.12, 0.12
        else:
            m.type = Marker.SPHERE
            m.pose.orientation.w = 1.0
            m.scale.x = m.scale.y = m.scale.z = 0.25
        m.color = ColorRGBA(0.1, 0.9, 0.2, 0.9)
        return m


def main() -> None:
    init_node(NODE)
    PointerNode()
    spin()
