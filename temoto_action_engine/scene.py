"""SceneDisplays: what a motion action draws in the operator's scene while it runs, through the Output Manager.

The paper's operator sees the robot's intent in the mixed-reality scene: the planned path, the footprint with
its stop zone, the hand and the target it gives. Those are displays like the view's, so they fail over the same
way: a display that fails (its RViz host crashed) is requested once more, and one that cannot be shown is said
to the operator as feedback and as a ``scene_failed`` event, never left looking shown.

Two rules keep the scene from ever holding the robot back:
- the displays are requested on their own thread: a motion never waits for RViz to start (4 s on these
  machines) before it moves, nor stops because a display failed;
- with no Output Manager running (a robot driven without a screen), nothing is requested and the operator is
  told so once.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Dict, List, Sequence

import rosgraph
import rospy

from temoto_core.errors import TemotoError

CLOSE_WAIT_S = 10.0            # the requests in flight when the action ends, at most
OM_SERVICE = '/%s/temoto_output_manager/load_rviz_plugin'


@dataclass(frozen=True)
class SceneDisplay:
    name: str                  # what the operator reads ("the planned path")
    display_type: str          # the Output Manager's abstract type ('path', 'marker array')
    topic: str


class SceneDisplays:
    def __init__(self, action, displays: Sequence[SceneDisplay]) -> None:
        self.action = action
        self.wanted = list(displays)
        self.shown: Dict[str, int] = {}             # name -> the Output Manager's resource id
        self._retried: set = set()
        self._failed: List[SceneDisplay] = []
        self._closing = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._run, name='scene of %s' % action.name, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        """Take every display off the scene; called as the action ends."""
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(CLOSE_WAIT_S)
        with self._cond:
            shown, self.shown = dict(self.shown), {}
        for name, resource_id in shown.items():
            try:
                self.action.output_manager.hide(resource_id)
            except (TemotoError, rospy.ROSException, OSError) as err:
                self.action.log_warn('taking %s off the scene: %s' % (name, err))

    # -- the scene's thread ----------------------------------------------------------------------------------
    def _om_running(self) -> bool:
        om = self.action.output_manager
        service = OM_SERVICE % (om.namespace or om.rr.namespace)
        try:
            rosgraph.Master(rospy.get_name()).lookupService(service)
            return True
        except rosgraph.MasterError:
            return False
        except OSError as err:
            self.action.log_warn('the master did not answer about %s: %s' % (service, err))
            return False

    def _run(self) -> None:
        if not self._om_running():
            self.action.feedback('no Output Manager runs: the scene does not show %s'
                                 % ', '.join(d.name for d in self.wanted))
            return
        for display in self.wanted:
            if self._closed():
                return
            self._show(display)
        while True:
            with self._cond:
                while not self._failed and not self._closing:
                    self._cond.wait(1.0)
                if self._closing:
                    return
                failed, self._failed = self._failed, []
            for display in failed:
                self._show_again(display)

    def _closed(self) -> bool:
        with self._cond:
            return self._closing

    def _show(self, display: SceneDisplay) -> bool:
        try:
            resource_id = self.action.output_manager.show_in_rviz(
                display.display_type, display.topic, name=display.name,
                on_status=lambda event, d=display: self._on_status(d, event))
        except (TemotoError, rospy.ROSException, OSError) as err:
            self.action.event('scene_failed', display=display.name, topic=display.topic, message=str(err))
            self.action.feedback('the scene does not show %s: %s' % (display.name, err))
            return False
        with self._cond:
            closing = self._closing
            if not closing:
                self.shown[display.name] = resource_id
        if closing:                       # the action ended while RViz started: nothing left on screen for it
            try:
                self.action.output_manager.hide(resource_id)
            except (TemotoError, rospy.ROSException, OSError) as err:
                self.action.log_warn('taking %s off the scene: %s' % (display.name, err))
            return False
        self.action.event('scene_shown', display=display.name, topic=display.topic)
        return True

    def _show_again(self, display: SceneDisplay) -> None:
        with self._cond:
            old = self.shown.pop(display.name, None)
        if old is not None:
            try:
                self.action.output_manager.hide(old)
            except (TemotoError, rospy.ROSException, OSError) as err:
                self.action.log_warn('releasing the failed display %s: %s' % (display.name, err))
        if display.name in self._retried:
            self.action.feedback('%s failed again: it is not shown any more' % display.name)
            return
        self._retried.add(display.name)
        if self._show(display):
            self.action.feedback('%s failed; shown again' % display.name)

    def _on_status(self, display: SceneDisplay, event) -> None:
        """From the registrar's thread: never blocks; the scene's thread shows it again."""
        if not event.failed:
            return
        self.action.event('scene_failed', display=display.name, topic=display.topic, message=event.message)
        with self._cond:
            self._failed.append(display)
            self._cond.notify_all()
