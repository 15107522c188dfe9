"""The virtual hand: an RViz interactive marker that the operator drags, served as a hand source.

A Leap Motion is one device on one desk; when it fails, the operator still has a mouse. The virtual hand is
the second hand source of the catalogue (``temoto_sensor_manager/config/hands.yaml``, ranked after the
tracker), so ``follow_hand`` fails over to it as the view fails over to another camera. It publishes what a
tracker publishes, ``temoto_core/HandSample`` at ``~rate`` (100 Hz): the palm is the marker's pose, always
in view; the grab is the marker's state:

- drag the marker (its arrows and rings) to move the palm;
- click the sphere, or choose "grab" / "open" in its menu, to close or open the hand. A grab after an open
  hand engages the clutch, as a fist does.

The marker starts on the tool it will move (``~start_frame`` in ``~frame``, from TF), so that the operator
grabs the arm where it is. Server ``~server`` (default ``virtual_hand``): RViz's InteractiveMarkers display
subscribes to ``<server>/update``, and sends ``<server>/feedback``.
Parameters: ``~frame`` (default ``left_base_link``), ``~start_frame`` (default ``left_tool0``), ``~rate``.
"""
from __future__ import annotations

import threading

import rospy
import tf2_ros
from geometry_msgs.msg import Pose
from interactive_markers.interactive_marker_server import InteractiveMarkerServer
from interactive_markers.menu_handler import MenuHandler
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import InteractiveMarker, InteractiveMarkerControl, InteractiveMarkerFeedback, Marker

from temoto_core import params
from temoto_core.msg import HandSample
from temoto_core.node import init_node, ok

NODE = 'virtual_hand'
START_WAIT_S = 2.0
OPEN_COLOUR, GRAB_COLOUR = ColorRGBA(0.2, 0.6, 1.0, 0.8), ColorRGBA(1.0, 0.3, 0.1, 0.9)


class VirtualHand:
    """The marker's pose and grab, as the operator leaves them."""

    def __init__(self, pose: Pose) -> None:
        self.lock = threading.Lock()
        self.pose = pose
        self.grab = 0.0

    def moved(self, pose: Pose) -> None:
        with self.lock:
            self.pose = pose

    def set_grab(self, grab: bool) -> None:
        with self.lock:
            self.grab = 1.0 if grab else 0.0

    def toggle(self) -> bool:
        with self.lock:
            self.grab = 0.0 if self.grab else 1.0
            return bool(self.grab)

    def sample(self, frame: str) -> HandSample:
        msg = HandSample(tracked=True)
        msg.header.stamp, msg.header.frame_id = rospy.Time.now(), frame
        with self.lock:
            msg.palm, msg.grab_strength = self.pose, self.grab
        return msg


def _marker(frame: str, pose: Pose, grabbing: bool) -> InteractiveMarker:
    im = InteractiveMarker()
    im.header.frame_id, im.name, im.scale = frame, 'virtual_hand', 0.2
    im.description = 'virtual hand: %s (click to %s)' % ('grabbing' if grabbing else 'open',
                                                        'open' if grabbing else 'grab')
    im.pose = pose
    ball = Marker(type=Marker.SPHERE, color=GRAB_COLOUR if grabbing else OPEN_COLOUR)
    ball.scale.x = ball.scale.y = ball.scale.z = 0.08
    ball.pose.orientation.w = 1.0
    click = InteractiveMarkerControl(name='grab', interaction_mode=InteractiveMarkerControl.BUTTON,
                                     always_visible=True, markers=[ball])
    click.orientation.w = 1.0
    im.controls.append(click)
    for axis, (x, y, z) in (('x', (1, 0, 0)), ('y', (0, 0, 1)), ('z', (0, 1, 0))):
        for mode, kind in ((InteractiveMarkerControl.MOVE_AXIS, 'move'),
                           (InteractiveMarkerControl.ROTATE_AXIS, 'rotate')):
            c = InteractiveMarkerControl(name='%s_%s' % (kind, axis), interaction_mode=mode)
            c.orientation.w, c.orientation.x, c.orientation.y, c.orientation.z = 1.0, x, y, z
            im.controls.append(c)
    return im


class VirtualHandNode:
    def __init__(self) -> None:
        self.frame = params.text('frame', 'left_base_link', empty=False)
        self.rate = params.number('rate', 100.0, above=0, maximum=500)
        self.hand = VirtualHand(self._start_pose(params.text('start_frame', 'left_tool0')))
        self.pub = rospy.Publisher('hand/sample', HandSample, queue_size=10, tcp_nodelay=True)
        self.server = InteractiveMarkerServer(params.text('server', NODE))
        self.menu = MenuHandler()
        self.menu.insert('grab', callback=lambda fb: self._grab(True))
        self.menu.insert('open', callback=lambda fb: self._grab(False))
        self._show()
        rospy.loginfo('%s: the marker on %s in %s; samples on %s at %.0f Hz', NODE, self.server.topic_ns, self.frame,
                      rospy.resolve_name('hand/sample'), self.rate)

    def _start_pose(self, start_frame: str) -> Pose:
        pose = Pose()
        pose.orientation.w = 1.0
        buffer = tf2_ros.Buffer()
        listener = tf2_ros.TransformListener(buffer)
        try:
            t = buffer.lookup_transform(self.frame, start_frame, rospy.Time(0), rospy.Duration(START_WAIT_S))
            pose.position.x, pose.position.y, pose.position.z = (t.transform.translation.x, t.transform.translation.y,
                                                                 t.transform.translation.z)
            pose.orientation = t.transform.rotation
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException) as err:
            rospy.logwarn('%s: %s not found in %s (%s): the marker starts at its origin', NODE, start_frame,
                          self.frame, err)
        finally:
            listener.unregister()
        return pose

    def _show(self) -> None:
        with self.hand.lock:
            pose, grabbing = self.hand.pose, bool(self.hand.grab)
        self.server.insert(_marker(self.frame, pose, grabbing), self._on_feedback)
        self.menu.apply(self.server, 'virtual_hand')
        self.server.applyChanges()

    def _grab(self, grab: bool) -> None:
        self.hand.set_grab(grab)
        self._show()

    def _on_feedback(self, fb: InteractiveMarkerFeedback) -> None:
        if fb.event_type == InteractiveMarkerFeedback.POSE_UPDATE:
            self.hand.moved(fb.pose)
        elif fb.event_type == InteractiveMarkerFeedback.BUTTON_CLICK:
            self.hand.toggle()
            self._show()

    def spin(self) -> None:
        rate = rospy.Rate(self.rate)
        while ok():
            self.pub.publish(self.hand.sample(self.frame))
            try:
                rate.sleep()
            except rospy.ROSInterruptException:
                break


def main() -> None:
    init_node(NODE)
    node = VirtualHandNode()
    node.spin()
    node.server.clear()
