"""What every simulated sensor driver shares: the cable, the robot state, the render loop.

A driver behaves like a real one whose cable can be pulled:
- it waits (bounded) for the sim's latched device states; a device that is
  unplugged at start, or missing, makes it fail like a real driver (crash mode:
  log an error and exit non-zero; stall mode: stay alive, publish nothing);
- while running, unplug/crash exits with code 1 within a few milliseconds of the
  states message (os._exit from the callback: a real crash does not clean up),
  and unplug/stall stops publishing for the rest of the process's life.

It reports its device on ``/diagnostics`` through ``diagnostic_updater``, as a
real driver does: OK while it publishes, ERROR "device not responding" when its
device is unplugged (stall mode) at its start, the case a silent driver cannot
otherwise tell from a slow one. A driver hung while running (stall mode after
the start) says nothing more, there or anywhere: that is the stall detector's case.
"""
from __future__ import annotations

import os
import sys
import threading
import time

import diagnostic_updater
import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from temoto_core import params
from temoto_core.node import ok
from sensor_msgs.msg import JointState

from vaultbot_sim.devices import Cable, CableWatch
from vaultbot_sim.motion import JointHistory
from vaultbot_sim.msg import DeviceStates
from vaultbot_sim.scene import RENDERERS, Scene
from vaultbot_sim.ticks import Ticks

EXIT_DEVICE_LOST = 1
DIAGNOSTICS_CONNECT_S = 1.0   # at most, for a subscriber of /diagnostics to connect before a start-up error


class DriverBase:
    """Subclasses set `device` and implement publish(stamp) using self.scene.

    Subclasses advertise their topics before calling this constructor, which waits for the sim and
    loads the scene: subscribers (RViz's roscpp takes ~0.25 s to connect to a new publisher on a busy
    machine) then connect meanwhile, and the first messages are not published to nobody.
    """

    device = ''
    default_rate = 10.0
    # it renders the lab from the robot's pose, so it waits for the robot's joint states (a render worker's
    # driver has no scene of its own here and still needs them)
    sees_the_lab = True

    def __init__(self):
        # relative by default: a driver started in a robot's namespace finds that robot's simulation
        try:
            self.sim_ns = rospy.resolve_name(params.text('sim_ns', 'vaultbot_sim', empty=False)).rstrip('/')
            self.rate = params.number('rate', self.default_rate, above=0, maximum=1000)
            self.startup_timeout = params.number('startup_timeout', 10.0, above=0)
            self.renderer = params.text('renderer', 'tiny', choices=RENDERERS)
        except params.ParamError as err:
            self.fail('%s: %s' % (self.device, err))
        self.cable = CableWatch(self.device)
        self.lock = threading.Lock()
        self.robot_hist = JointHistory()
        self.world_hist = JointHistory()
        self._states_seen = threading.Event()
        self._js_seen = threading.Event()
        self.publishing = False
        self.hung = False                 # stalled while running: silent everywhere, /diagnostics included
        self.diagnostics = diagnostic_updater.Updater()
        self.diagnostics.setHardwareID(self.device)
        self.diagnostics.add(self.device, self._device_status)
        # its own thread: the updater reads ~diagnostic_period from the master, which must never delay data
        threading.Thread(target=self._report_periodically, name='diagnostics', daemon=True).start()
        rospy.Subscriber(self.sim_ns + '/device_states', DeviceStates, self._on_states, queue_size=5,
                         tcp_nodelay=True)
        if not self._states_seen.wait(self.startup_timeout):
            self.fail(f'{self.device}: no device found: nothing on {self.sim_ns}/device_states '
                      f'after {self.startup_timeout:.0f} s (is vaultbot_sim running?)')
        if self.cable.verdict == 'stall':
            rospy.logwarn('%s: device not responding (unplugged, stall): publishing nothing', self.device)
            self._report_now()
        self.robot_urdf = self._param(self.sim_ns + '/robot_urdf')
        self.world_urdf = self._param(self.sim_ns + '/world_urdf')
        self.frame_prefix = str(rospy.get_param(self.sim_ns + '/frame_prefix', ''))    # its robot's TF frames
        self.scene = self.make_scene()
        self.cfg: tuple[dict, dict] = ({}, {})
        if not self.sees_the_lab:
            return      # the operator's hand tracker: where the robot is means nothing to it
        rospy.Subscriber('joint_states', JointState, self._on_js, self.robot_hist, queue_size=20,
                         tcp_nodelay=True)
        rospy.Subscriber(self.sim_ns + '/world_joint_states', JointState, self._on_js, self.world_hist,
                         queue_size=20, tcp_nodelay=True)
        if not self._js_seen.wait(self.startup_timeout):
            self.fail(f'{self.device}: no {rospy.resolve_name("joint_states")} after {self.startup_timeout:.0f} s')

    def make_scene(self) -> Scene | None:
        return Scene(self.robot_urdf, self.world_urdf, renderer=self.renderer)

    def _param(self, name: str) -> str:
        deadline = time.monotonic() + self.startup_timeout
        while time.monotonic() < deadline and ok():
            if rospy.has_param(name):
                return rospy.get_param(name)
            time.sleep(0.05)
        self.fail(f'{self.device}: parameter {name} not set (is vaultbot_sim running?)')

    def _device_status(self, stat: diagnostic_updater.DiagnosticStatusWrapper):
        if self.cable.verdict == 'stall':
            stat.summary(DiagnosticStatus.ERROR, '%s: device not responding (cable unplugged)' % self.device)
        elif self.publishing:
            stat.summary(DiagnosticStatus.OK, 'publishing at %.0f Hz' % self.rate)
        else:
            stat.summary(DiagnosticStatus.OK, 'starting')
        return stat

    def _report_now(self) -> None:
        """Publish the device's status at once. A publisher made a moment ago drops what it sends before its
        subscribers connect (ROS 1), so a start-up error waits a bounded moment for one."""
        pub = self.diagnostics.publisher
        deadline = time.monotonic() + DIAGNOSTICS_CONNECT_S
        while not pub.get_num_connections() and time.monotonic() < deadline and ok():
            time.sleep(0.01)
        self.diagnostics.force_update()

    def _report_periodically(self) -> None:
        while ok() and not self.hung:
            self.diagnostics.update()         # rate-limited to its ~diagnostic_period (1 s)
            time.sleep(0.25)

    def fail(self, text: str) -> None:
        """Exit the way a driver does when it cannot reach its device."""
        rospy.logerr(text)
        sys.stderr.flush()
        time.sleep(0.005)  # give the rosout publisher a moment; still well inside 100 ms
        os._exit(EXIT_DEVICE_LOST)

    def _on_states(self, msg: DeviceStates) -> None:
        cables = [Cable(d.name, d.plugged, d.mode) for d in msg.devices]
        before = self.cable.verdict
        verdict = self.cable.update(cables)
        if before == 'run' and verdict == 'stall':
            self.hung = True
        self._states_seen.set()
        if verdict == 'crash':
            self.fail(f'{self.device}: device disconnected (cable unplugged): exiting')

    def _on_js(self, msg: JointState, hist: JointHistory) -> None:
        with self.lock:
            hist.add(msg.header.stamp.to_sec(), msg.name, msg.position, msg.velocity)
        if hist is self.robot_hist:
            self._js_seen.set()

    def pose_scene(self, t: float) -> None:
        with self.lock:
            robot = self.robot_hist.cfg_at(t) or {}
            world = self.world_hist.cfg_at(t) or {}
        self.cfg = (robot, world)
        if self.scene is not None:
            self.scene.set_robot(robot)
            self.scene.set_world(world)

    def publish(self, stamp: rospy.Time) -> None:
        raise NotImplementedError

    def spin(self) -> None:
        ticks = Ticks(1.0 / self.rate)
        first = True
        while ok():
            if self.cable.verdict == 'run':
                stamp = rospy.Time.now()
                self.pose_scene(stamp.to_sec())
                self.publish(stamp)
                if first:
                    rospy.loginfo('%s: publishing at %.0f Hz', self.device, self.rate)
                    self.publishing = True
                    first = False
            ticks.wait()
        self.close()

    def close(self) -> None:
        if self.scene is not None:
            self.scene.close()
