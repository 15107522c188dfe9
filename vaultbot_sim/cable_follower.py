"""What a simulated controller's process does with its cable (``temoto sim unplug DEVICE --mode ...``).

As a real controller that loses its hardware: ``crash`` makes it exit at once with code 1, without
cleaning up; ``stall`` makes it fall silent for the rest of its life, its process up. The sensor
drivers (``driver.py``) add their diagnostics to the same rule.
"""
from __future__ import annotations

import os
import sys
import threading

import rospy

from vaultbot_sim.devices import Cable, CableWatch
from vaultbot_sim.msg import DeviceStates

EXIT_DEVICE_LOST = 1


class CableFollower:
    def __init__(self, device: str, what: str, sim_ns: str) -> None:
        self.cable = CableWatch(device)
        self.what = what                      # 'left_arm: arm controller', in its log lines
        self.seen = threading.Event()         # the first device states arrived
        rospy.Subscriber(sim_ns + '/device_states', DeviceStates, self._on_states, queue_size=5, tcp_nodelay=True)

    @property
    def running(self) -> bool:
        return self.cable.verdict == 'run'

    def _on_states(self, msg: DeviceStates) -> None:
        verdict = self.cable.update([Cable(d.name, d.plugged, d.mode) for d in msg.devices])
        self.seen.set()
        if verdict == 'crash':
            fail('%s disconnected (cable unplugged): exiting' % self.what)
        if verdict == 'stall':
            rospy.logwarn_once('%s not responding (cable unplugged, stall): silent' % self.what)


def fail(text: str) -> None:
    """Exit as a controller does when it loses its hardware: at once, without cleaning up."""
    rospy.logerr(text)
    sys.stderr.flush()
    os._exit(EXIT_DEVICE_LOST)
