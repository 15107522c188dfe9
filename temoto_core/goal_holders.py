"""Who holds a goal of a motion node (the navigator, a manipulator, an arm's or a gripper's controller), watched
through their connections. In the core, because a controller that stands in for a robot's driver (``vaultbot_sim``)
watches its goal's client the same way: a manipulator SIGKILLed mid-trajectory left its arm running the trajectory
to its end, with nobody behind it.

The kernel closes a process's connections the moment it dies, so a connection's end is the fastest news
of a holder's death ROS 1 can give, without a heartbeat. Two holders are watched:

- the goal's action client: its subscription to the status the server publishes, read for an end of file
  on every look (``rospy_internals.live_subscribers``). A client not among the status's subscribers
  ``CLIENT_CONNECT_S`` after its goal came (it died before its connection was made: chaos, seed 17, step
  3471, a client SIGKILLed 5 ms after sending a drive, which went on for 3 s; or it never subscribes,
  ``rostopic pub``) is asked at its node's address, every ``PROBE_PERIOD_S``, on a thread of its own: a
  kernel that refuses the connection says the process died. A goal whose sender is not a node the master
  knows, or a tool that sends and forgets (RViz's ``move_base_simple``), has nobody to watch and is never
  orphaned.
  A client cut off (the operator's link down) closes nothing, and TCP would retransmit for minutes: a
  client whose kernel has acknowledged none of the status (sent at 5 Hz) for ``CLIENT_UNREACHABLE_S``
  while it was retransmitted counts as gone (``rospy_internals.unreachable``). Its client let go by then
  (its registrar calls the Robot Manager cut off after 0.7 s), and nobody could stop the robot (chaos,
  history 5: a drive went on until the link came back). The connection stays, and carries the goal's end
  to the client once the link is back;
- the Robot Manager that started the node: the latched topic it publishes to the node, once seen, its
  connection read for an end of file the same way (``rospy_internals.live_publishers``).
"""
from __future__ import annotations

import http.client
import threading
import time
import xmlrpc.client
from typing import Optional

import actionlib
import rosgraph
import rospy

from temoto_core.master_lookup import lookup_node, node_refuses
from temoto_core.rospy_internals import live_publishers, live_subscribers
from temoto_core.wait import wait_for

OWNER_LOOK_S = 0.05            # how often the manager's connection is looked for until it is first seen
# s a goal's client may acknowledge nothing, while the status is retransmitted, before it counts as gone: under
# the client side's own 0.7 s (a registrar's owner liveness); a reachable client's kernel acknowledges in ms
CLIENT_UNREACHABLE_S = 0.4
# s a goal's client has to appear among the status's subscribers before its node is asked whether it lives (an
# actionlib client subscribes before it sends: its connection comes within ms, or tens of them when loaded)
CLIENT_CONNECT_S = 0.2
PROBE_PERIOD_S = 0.25          # s between two asks of a client that is still not among them
PROBE_TIMEOUT_S = 1.0          # the master's answer and the node's port; no answer is not a death


class GoalHolders:
    def __init__(self, node: str, owner: Optional[rospy.Subscriber], server: actionlib.ActionServer,
                 fire_and_forget: str = '') -> None:
        """``node``: what the node is, for the reasons (``navigator``); ``owner``: the subscription to the
        Robot Manager's latched topic (None: not started by one); ``server``: the action server (its status
        publisher appears when it starts); ``fire_and_forget``: the prefix of goal ids that have no client
        to watch."""
        self._node = node
        self._owner = owner
        self._server = server
        self._fire_and_forget = fire_and_forget
        self._owner_seen = False
        self._client_seen = False
        self._goal_at = 0.0
        self._goals = 0                        # the goal a probe's answer belongs to
        self._probe_lock = threading.Lock()
        self._probing = False
        self._probed_at = 0.0
        self._died = ''                        # the unseen client the last probe of this goal found dead
        # looked for until seen, not only when a goal comes: a manager that dies before the first goal must
        # still count as seen, or that goal would be taken as one with no manager, and never orphaned
        self._looking = rospy.Timer(rospy.Duration(OWNER_LOOK_S), self._look_for_owner) if owner else None

    def _look_for_owner(self, _event) -> None:
        if self._owner_connected():
            self._owner_seen = True
            self._looking.shutdown()

    def wait_for_owner(self, timeout: float) -> bool:
        """Wait until the Robot Manager's connection has been seen (True), or ``timeout`` passes (False). A node
        calls it before it serves goals: a manager that dies before its connection is first seen would leave the
        next goal taken for one with no manager, and accepted (a CI run: the goal ran until the ER Manager
        stopped the navigator). A node started by nobody (no owner topic) does not wait."""
        if self._owner is None or self._owner_seen:
            return True
        try:
            wait_for(self._owner_connected, timeout, 'the Robot Manager\'s connection')
        except TimeoutError:
            return False
        self._owner_seen = True
        return True

    def new_goal(self) -> None:
        """A new goal: its client has not been seen yet."""
        self._client_seen = False
        with self._probe_lock:
            self._goals += 1
            self._goal_at, self._probed_at, self._died = time.monotonic(), 0.0, ''

    def owner_away(self) -> Optional[str]:
        """Why a new goal must be refused now: the Robot Manager that started this node was seen and has no
        connection to it (it died, or is being respawned and has not reached this node again), or None."""
        if self._owner is None:
            return None
        if self._owner_connected():
            self._owner_seen = True
            return None
        if self._owner_seen:
            return 'the Robot Manager that started this %s is away (dead, or restarting): nothing moves until ' \
                   'it is back' % self._node
        return None

    def _owner_connected(self) -> bool:
        """The manager's latched topic reaches this node now: read from the socket, not from rospy's count,
        which lags the manager's death by however long the receive thread waits for a CPU (a goal sent right
        after the death was accepted and moved the base, in a CI run)."""
        return bool(live_publishers(self._owner))

    def gone(self, goal_id: str) -> Optional[str]:
        """Why the goal ``goal_id`` has nobody left to want it, or None."""
        if self._owner is not None:
            if self._owner_connected():
                self._owner_seen = True
            elif self._owner_seen:
                return 'the Robot Manager that started this %s is gone' % self._node
        if self._fire_and_forget and goal_id.startswith(self._fire_and_forget):
            return None
        client = goal_id.split('-', 1)[0]
        if client in live_subscribers(self._server.status_pub, CLIENT_UNREACHABLE_S):
            self._client_seen = True
        elif self._client_seen:
            return 'its client %s is gone' % client
        else:
            return self._unseen(client)
        return None

    def _unseen(self, client: str) -> Optional[str]:
        """A client never seen among the status's subscribers: dead if its node's kernel refuses a connection
        (asked on a thread: this runs in the node's control loop)."""
        now = time.monotonic()
        with self._probe_lock:
            if self._died:
                return 'its client %s is gone (it died before its connection to the status was made)' % client
            if now - self._goal_at >= CLIENT_CONNECT_S and not self._probing \
                    and now - self._probed_at >= PROBE_PERIOD_S:
                self._probing, self._probed_at = True, now
                threading.Thread(target=self._probe, args=(client, self._goals), daemon=True,
                                 name='goal-client-probe').start()
        return None

    def _probe(self, client: str, goal: int) -> None:
        dead = False
        try:
            uri = lookup_node(rosgraph.get_master_uri(), client, PROBE_TIMEOUT_S)
            dead = uri is not None and node_refuses(uri, PROBE_TIMEOUT_S)
        except (OSError, xmlrpc.client.Error, http.client.HTTPException) as err:   # the master out of reach: the
            # next look asks again
            rospy.logdebug('%s: could not ask after the client %s: %s', self._node, client, err)
        with self._probe_lock:
            self._probing = False
            if dead and goal == self._goals:
                self._died = client
