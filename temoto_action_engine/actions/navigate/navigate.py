"""navigate: "Robot please go" to the goal pointed in RViz, or "go home" to a place of the robot's description.

The action holds the robot's navigation for the drive (``RobotAction``) and sends one move_base goal to the
navigator. A place said by name is looked up in the description the Robot Manager serves; "go" or "go
there" takes the goal pointed with RViz's "2D Nav Goal" or "Publish Point" (the pointer node,
``temoto_operator/pointer_node.py``), which then leaves the scene. A pointed point has no heading: the
robot faces it from where it stands.

It says how far is left every 2 s, and the obstacle source's failovers as they come. It ends FINISHED on
arrival; FAILED with the navigator's reason (refused, blocked, no fresh obstacles) or the robot's (a part
failed); stopped (the operator's "stop"), the goal is cancelled and the robot stops.
"""
import math

import rospy
import tf2_ros
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import PoseStamped
from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
from std_msgs.msg import Float32, String

from temoto_action_engine.action_base import ActionError
from temoto_action_engine.robot_action import RobotAction
from temoto_action_engine.scene import SceneDisplay
from temoto_core.latched import NoPublisher, latched_message
from temoto_operator.pointer_node import pointed_of
from temoto_operator.pointing import BadPointing

POINTED_WAIT_S = 10.0         # the pointer's latched goal reaches a new subscriber within this, even when busy
TF_WAIT_S = 5.0               # where the robot stands, from a new TF listener
POINTED_WORDS = ('', 'there', 'pointed', 'goal', 'target')
PLACE_FRAME = 'world'         # the frame of a description's named places (the map's)
DRIVE_TIMEOUT_S = 600.0


class Navigate(RobotAction):
    def on_start(self):
        place = (self.input('place') or '').strip().lower()
        info = self.claim_robot('navigation')
        places = info.get('place_poses') or {}
        if place in POINTED_WORDS:
            self.target, self.target_text = self._pointed(info), 'the pointed goal'
        elif place.replace(' ', '_') in places:
            name = place.replace(' ', '_')
            self.target, self.target_text = self._pose(PLACE_FRAME, *places[name]), name
        else:
            raise ActionError('no place "%s" for %s: say one of %s, or point a goal in RViz and say "go"'
                              % (place, info['name'], ', '.join(sorted(places)) or 'none'))
        self.client = self.client('move_base', MoveBaseAction)
        self.show_scene(SceneDisplay('the planned path', 'path', self.navigator_topic('plan')),
                        SceneDisplay('the footprint and its stop zone', 'marker array',
                                     self.navigator_topic('scene')))

    def execute(self):
        left = {'m': float('nan')}
        sub = rospy.Subscriber(self.robot_topic('move_base/distance_remaining'), Float32,
                               lambda m: left.update(m=m.data), queue_size=1)
        p = self.target.pose.position
        self.event('driving', to=self.target_text, x=round(p.x, 3), y=round(p.y, 3), frame=self.target.header.frame_id)
        self.feedback('driving to %s' % self.target_text)
        try:
            state, text, _ = self.run_goal(self.client, MoveBaseGoal(target_pose=self.target),
                                           'the drive to %s' % self.target_text, DRIVE_TIMEOUT_S,
                                           lambda: '%.1f m to go' % left['m'] if math.isfinite(left['m']) else None)
        finally:
            sub.unregister()
        if not self.action_ok():
            return
        if text.startswith('halted:'):         # the operator's stop reached the navigator first
            self.event('halted', at=self.target_text, reason=text)
            self.feedback('stopped on the way to %s' % self.target_text)
            return
        if state != GoalStatus.SUCCEEDED:
            raise ActionError('the drive to %s ended %s: %s' % (self.target_text, self.state_name(state), text))
        self.event('arrived', at=self.target_text)
        self.feedback('arrived at %s' % self.target_text)

    # -- targets ----------------------------------------------------------------------------------------------
    @staticmethod
    def _pose(frame, x, y, yaw) -> PoseStamped:
        pose = PoseStamped()
        pose.header.frame_id, pose.header.stamp = frame, rospy.Time.now()
        pose.pose.position.x, pose.pose.position.y = float(x), float(y)
        pose.pose.orientation.z, pose.pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
        return pose

    def _pointed(self, info) -> PoseStamped:
        """The pointer's goal, marked used; a point gets the heading from the robot towards it."""
        topic = '/%s/pointed_goal' % self.context.namespace
        try:
            msg = latched_message(topic, PoseStamped, POINTED_WAIT_S)
        except NoPublisher:
            raise ActionError('no pointed goal: nothing publishes %s (is the pointer running?)' % topic) from None
        except TimeoutError as err:
            raise ActionError('no pointed goal: %s' % err) from None
        try:
            pointed = pointed_of(msg)
        except BadPointing as err:
            raise ActionError('the pointed goal is not one: %s' % err) from None
        if pointed is None:
            raise ActionError('no goal is pointed: point one with RViz\'s "2D Nav Goal" or "Publish Point", '
                              'or say a place (%s)' % ', '.join(sorted(info.get('place_poses') or {})))
        yaw = pointed.yaw()
        if yaw is None:
            yaw = self._facing(pointed, info.get('base_frame') or 'base_link')
        used = rospy.Publisher('/%s/pointed_goal/used' % self.context.namespace, String, queue_size=1, latch=True)
        used.publish(String('%s/%s' % (self.context.graph_name, self.name)))
        self._used_pub = used             # kept until the action ends, so the latched word reaches the pointer
        return self._pose(pointed.frame, pointed.x, pointed.y, yaw)

    def _facing(self, pointed, base_frame: str) -> float:
        buffer = tf2_ros.Buffer()
        listener = tf2_ros.TransformListener(buffer)
        try:
            t = buffer.lookup_transform(pointed.frame, base_frame, rospy.Time(0), rospy.Duration(TF_WAIT_S))
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as err:
            raise ActionError('the pointed point has no heading, and where the robot stands in %s is not '
                              'known: %s' % (pointed.frame, err)) from None
        finally:
            listener.unregister()
        at = t.transform.translation
        return math.atan2(pointed.y - at.y, pointed.x - at.x)
