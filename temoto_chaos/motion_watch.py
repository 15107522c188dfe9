"""chaos_motion_watch: the simulation's ground truth of motion, for the chaos checker (``motion_truth.py``).

It runs on the robot's host, beside the simulation and the navigator, so a cut link does not blind it: it
hears the sim's own states and the obstacle sources as the navigator does. The runner spares it when the
robot loses power (it is the test's instrument, not the robot's), and asks it over a Unix socket, which
every network namespace reaches: ``{"op": "since", "seq": n}`` answers the events numbered above n.

Which obstacle source the navigator drives on is asked of the master every ``ACTIVE_LOOK_S``: the topic among
the sources that the navigator's node subscribes to (``~navigator``, its name in the robot's namespace). Its
own word (a log line, the Robot Manager's announcement) would be the stack judging itself.
"""
from __future__ import annotations

import http.client
import threading
import xmlrpc.client

import rosgraph
import rospy

from temoto_core import control_socket, params
from temoto_core.master_lookup import subscriptions_of
from temoto_core.node import init_node, spin
from temoto_core.serialized import header_stamp
from vaultbot_sim.msg import ArmState, BaseState, Contact, GripperState

from .motion_truth import GroundTruth

NODE_NAME = 'chaos_motion_watch'
TICK_S = 0.1
ACTIVE_LOOK_S = 0.2          # between two asks of the master for the navigator's subscriptions
LOOK_TIMEOUT_S = 1.0


class MotionWatch:
    """The subscriptions, feeding one ``GroundTruth`` under a lock."""

    def __init__(self, robot_namespace: str, navigator: str = 'vaultbot_navigator') -> None:
        self.truth = GroundTruth()
        self.lock = threading.Lock()
        ns = '/' + robot_namespace.strip('/') if robot_namespace.strip('/') else ''
        self._ns = ns
        self._navigator = '%s/%s' % (ns, navigator.strip('/'))
        sim = ns + '/vaultbot_sim/'
        self._subs = [
            rospy.Subscriber(sim + 'base_state', BaseState, self._on_base, queue_size=100, tcp_nodelay=True),
            rospy.Subscriber(sim + 'arm_states', ArmState, self._on_arm, queue_size=100, tcp_nodelay=True),
            rospy.Subscriber(sim + 'gripper_state', GripperState, self._on_gripper, queue_size=100, tcp_nodelay=True),
            rospy.Subscriber(sim + 'contacts', Contact, self._on_contact, queue_size=100, tcp_nodelay=True)]
        # the obstacle sources: only when a message came matters, never what it holds
        for source in self.truth.sources:
            self._subs.append(rospy.Subscriber('%s/%s' % (ns, source), rospy.AnyMsg,
                                               lambda m, s=source: self._on_obstacle(s, m), queue_size=1))
        self._timer = rospy.Timer(rospy.Duration(TICK_S), self._tick)
        self._shut = threading.Event()
        rospy.on_shutdown(self._shut.set)
        threading.Thread(target=self._look_for_active, name='active source', daemon=True).start()

    def _look_for_active(self) -> None:
        """The navigator's obstacle subscription, from the master, on a thread of its own (a slow master must not
        hold the samples up)."""
        master = rosgraph.get_master_uri()
        while not self._shut.wait(ACTIVE_LOOK_S):
            try:
                topics = subscriptions_of(master, self._navigator, LOOK_TIMEOUT_S)
            except (OSError, xmlrpc.client.Error, http.client.HTTPException) as err:
                rospy.logdebug('%s: the master did not say what %s reads: %s', NODE_NAME, self._navigator, err)
                topics = None
            if topics is not None:
                reads = [s for s in self.truth.sources if '%s/%s' % (self._ns, s) in topics]
                with self.lock:
                    self.truth.navigator_reads(reads)

    def _on_base(self, m: BaseState) -> None:
        with self.lock:
            self.truth.base(m.header.stamp.to_sec(), m.linear, m.angular)

    def _on_arm(self, m: ArmState) -> None:
        with self.lock:
            self.truth.arm(m.header.stamp.to_sec(), m.arm, m.held, m.speed)

    def _on_gripper(self, m: GripperState) -> None:
        with self.lock:
            self.truth.gripper(m.header.stamp.to_sec(), m.speed)

    def _on_contact(self, m: Contact) -> None:
        with self.lock:
            self.truth.contact(m.header.stamp.to_sec(), m.robot_link, m.object_link, m.speed)

    def _on_obstacle(self, source: str, raw: rospy.AnyMsg) -> None:
        now = rospy.get_time()
        with self.lock:
            self.truth.obstacle(now, source, header_stamp(getattr(raw, '_buff', None)))

    def _tick(self, _event) -> None:
        now = rospy.get_time()
        with self.lock:
            self.truth.tick(now)

    def handle(self, cmd: dict) -> dict:
        if cmd.get('op') == 'since':
            with self.lock:
                return dict(self.truth.since(int(cmd.get('seq', 0))), now=rospy.get_time())
        return {'ok': False, 'error': 'unknown op %r: since' % (cmd.get('op'),)}


def main() -> None:
    init_node(NODE_NAME)
    watch = MotionWatch(params.text('robot_namespace', 'chaos'), params.text('navigator', 'vaultbot_navigator'))
    server = control_socket.serve(params.text('control_socket', '', empty=False), watch.handle, 'motion-watch-control')
    try:
        spin()
    finally:
        server.shutdown()
