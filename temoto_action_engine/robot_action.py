"""RobotAction: the base of the actions that move the robot (navigate, gripper, follow_hand).

A motion action claims the robot's feature through the Robot Manager for exactly as long as it runs: the
robot moves for a holder, and when the holder goes (the action stops, its worker dies) the motion nodes see
its goal's client go and stop (``temoto_core/goal_holders.py``). Its own failure policy is to
stop, never to reload silently under a moving robot: a part that fails reaches it as FAILED, the goal is
cancelled, and the action ends FAILED with the part's reason.

It also gives what each of them needs: the robot's description as the manager serves it, its topics in the
robot's ROS namespace, and one actionlib goal run to its end, with the operator's stop and the robot's
failures watched while it runs.
"""
from __future__ import annotations

import time
from typing import Any, Callable, Optional

import rospy
from actionlib_msgs.msg import GoalStatus

from temoto_core.action_client import TrackingActionClient
from temoto_core.errors import TemotoError

from .action_base import ActionBase, ActionError
from .scene import SceneDisplay, SceneDisplays

SERVER_WAIT_S = 30.0           # a part's action server appears within its start (the load returned already)
POLL_S = 0.1                   # the goal loop's wake-up when nothing is posted
PROGRESS_PERIOD_S = 2.0        # between two progress sentences
STATE_NAMES = {v: k for k, v in vars(GoalStatus).items() if k.isupper() and isinstance(v, int)}


class RobotAction(ActionBase):
    """An action that holds one feature of a robot while it runs."""

    robot_info: dict = {}
    loaded = None
    _scene = None

    def claim_robot(self, feature: str) -> dict:
        """Load the robot's ``feature`` (the ``robot`` input names one, else the manager's first with it)."""
        robot_name = ''
        if 'robot' in self.context.descriptor.inputs:
            robot_name = (self.context.inputs.get('robot') or '').strip()
        try:
            info = self.robot_manager.robot_with(feature, robot_name if '/' not in robot_name else '')
        except LookupError as err:
            raise ActionError(str(err)) from None
        except (OSError, rospy.ROSException, ValueError) as err:
            raise ActionError('the Robot Manager does not answer: %s' % err) from None
        self.robot_info = info
        self.feedback('loading %s of %s' % (feature, info['name']))
        try:
            self.loaded = self.robot_manager.load_robot([feature], robot_name=info['name'], on_status=self.post)
        except TemotoError as err:
            raise ActionError('could not load %s of %s: %s' % (feature, info['name'], err)) from None
        return info

    def show_scene(self, *displays: SceneDisplay) -> None:
        """Draw ``displays`` in the operator's scene while the action runs (``scene.py``: on their own thread;
        the motion never waits for them)."""
        self._scene = SceneDisplays(self, displays)
        self._scene.start()

    def release_resources(self) -> list:
        if self._scene is not None:
            self._scene.close()           # no request after this; then the registrar unloads what is left
        return super().release_resources()

    def navigator_topic(self, name: str) -> str:
        """A private topic of the held robot's navigator (``plan``, ``scene``)."""
        return self.robot_topic('%s/%s' % (self.robot_info.get('navigator') or 'navigator', name))

    def robot_topic(self, name: str) -> str:
        """``name`` in the robot's ROS namespace (where its manager started its parts)."""
        return (self.robot_info.get('ros_namespace') or '/').rstrip('/') + '/' + name.lstrip('/')

    def client(self, name: str, action_spec) -> TrackingActionClient:
        topic = self.robot_topic(name)
        client = TrackingActionClient(topic, action_spec)
        deadline = time.monotonic() + SERVER_WAIT_S
        while not client.wait_for_server(rospy.Duration(0.5)):
            if not self.action_ok():
                raise ActionError('stopped while waiting for %s' % topic)
            if time.monotonic() > deadline:
                raise ActionError('no action server on %s after %.0f s' % (topic, SERVER_WAIT_S))
        return client

    def robot_event(self, event) -> Optional[str]:
        """A status of the held robot: a failure's reason (the caller stops), or None (said as feedback)."""
        if self.loaded is None or event.resource_id != self.loaded.resource_id:
            return None
        if event.failed:
            return '%s failed: %s' % (self.robot_info.get('name', 'the robot'), event.message)
        self.feedback(event.message)
        return None

    def run_goal(self, client: TrackingActionClient, goal, what: str, timeout: float,
                 progress: Callable[[], Optional[str]] = lambda: None) -> tuple[int, str, Any]:
        """Send ``goal`` and wait for its end. Stopping the action cancels it (the motion stops) and returns
        PREEMPTED; a failure of the held robot cancels it and ends the action FAILED; ``progress()`` is said
        every 2 s. Returns (state, status text, result)."""
        client.send_goal(goal)
        deadline = time.monotonic() + timeout
        said = time.monotonic()
        try:
            while not client.ended():
                item = self.next_item(POLL_S)
                if not self.action_ok():
                    client.cancel_goal()
                    return GoalStatus.PREEMPTED, 'stopped: %s cancelled' % what, None
                if item is not None:
                    why = self.robot_event(item)
                    if why is not None:
                        raise ActionError('%s; %s cancelled' % (why, what))
                now = time.monotonic()
                if now > deadline:
                    raise ActionError('%s did not end within %.0f s: cancelled' % (what, timeout))
                if now - said >= PROGRESS_PERIOD_S:
                    said = now
                    text = progress()
                    if text:
                        self.feedback(text)
        except ActionError:
            client.cancel_goal()
            raise
        return client.get_state(), client.get_goal_status_text(), client.get_result()

    @staticmethod
    def state_name(state: int) -> str:
        return STATE_NAMES.get(state, str(state))
