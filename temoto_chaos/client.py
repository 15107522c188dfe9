"""A chaos client: a registrar of its own in its own process, loading and unloading sensors, processes,
tracked objects and displays when told.

The runner drives it over a Unix socket (one JSON object per line, one answer per line), so it reaches the
client whatever the ROS graph is doing. The client acknowledges what the Sensor Manager acknowledged, and
keeps, for the checker, what a real consumer would know: the resources it holds, every status it heard
for them, and how long each call took against its deadline. It sets no failure policy of its own beyond
recording: a FAILED resource stays held (failed) until the runner unloads it, as an action's would until
its policy runs.
"""
from __future__ import annotations

import collections
import contextlib
import os
import threading
import time
from typing import Callable, Deque, Dict, Iterator, List, Optional

import rospy

from temoto_core import control_socket, params
from temoto_core.errors import TemotoError
from temoto_core.node import init_node, spin
from temoto_core.rr import StatusEvent
from temoto_context_manager.interface import ContextManagerInterface
from temoto_er_manager.interface import ERManagerInterface
from temoto_output_manager.interface import OutputManagerInterface
from temoto_robot_manager.interface import RobotManagerInterface
from temoto_sensor_manager.interface import SensorManagerInterface

from .motion_client import Journal, MotionClient

NODE_NAME = 'chaos_client'     # the runner names each incarnation (__name:=chaos_client_<client>_<generation>)
RECENT_STATUSES = 20
THROTTLE = '/usr/lib/topic_tools/throttle'     # the process a client runs (the chaos ER config allows it)
HAND_TYPE, HAND_KEY = 'hand', 'hand_data'      # the hand source a servo may follow (hands.yaml)


class ChaosClient:
    """The state a consumer knows, and the operations the runner asks of it."""

    def __init__(self, namespace: str, station_namespace: str = '', journal: str = '') -> None:
        self.namespace = namespace
        self.sensors = SensorManagerInterface(namespace=namespace)
        rr = self.sensors.rr         # one registrar for every manager's resources
        self.processes = ERManagerInterface(rr=rr, namespace=namespace)
        self.context = ContextManagerInterface(rr=rr, namespace=namespace)
        self.screen = OutputManagerInterface(rr=rr, namespace=station_namespace) if station_namespace else None
        self.robots = RobotManagerInterface(rr=rr, namespace=namespace)
        # the motions it holds on the robot (history 5), journaled for the checker
        self.motion = MotionClient(Journal(journal), rospy.get_name()) if journal else None
        self.robot_info: Dict[int, dict] = {}      # a held robot's id -> the manager's description of it
        # how each kind of held resource is released
        self.releases = {'sensor': self.sensors.stop_sensor, 'process': self.processes.unload,
                         'tracked': self.context.stop, 'display': self.screen.hide if self.screen else None,
                         'robot': self._release_robot}
        self.lock = threading.Lock()
        self.held: Dict[int, dict] = {}        # local id -> {'kind', 'what' (its request), 'failed': message or ''}
        # what the checker needs stays bounded over a history of any length: the FAILED heard for what is
        # still held, the last statuses (to read a report), and per operation its count and slowest call
        self.failed_heard: Dict[int, str] = {}     # local id -> the FAILED's message, until it is unloaded
        self.recent: Deque[dict] = collections.deque(maxlen=RECENT_STATUSES)
        self.calls: Dict[str, dict] = {}           # op -> {'count', 'failed', 'max_s'}: held to its deadline
        self.unexpected: List[str] = []            # a call that raised something other than a TemotoError
        # the calls under way (the runner may ask for the state meanwhile): the checker does not hold a
        # resource whose load or unload is under way to what is settled
        self.pending: Dict[int, dict] = {}         # call number -> {'op', 'kind', 'id' (an unload's)}
        self._calls_started = 0
        self.hand_topics: Dict[int, str] = {}      # a held hand source's id -> its sample topic

    def _on_status(self, ev: StatusEvent) -> None:
        with self.lock:
            self.recent.append({'id': ev.resource_id, 'code': ev.code.name, 'message': ev.message})
            robot = False
            if ev.failed:
                self.failed_heard[ev.resource_id] = ev.message or 'FAILED'
                if ev.resource_id in self.held:
                    self.held[ev.resource_id]['failed'] = ev.message or 'FAILED'
                    robot = self.held[ev.resource_id]['kind'] == 'robot'
        if robot and self.motion is not None:
            self.motion.robot_failed(ev.resource_id, ev.message)     # a motion action's policy: stop

    def _load(self, kind: str, what: str, load: Callable[[], object], resource_id: Callable[[object], int],
              answer: Callable[[object], dict]) -> dict:
        """One load through an interface: acknowledged (held, answered with ``answer``) or refused."""
        t0 = time.monotonic()
        with self._under_way('load', kind):
            try:
                result = load()
            except TemotoError as e:
                self._call('load ' + kind, t0, False)
                return {'ok': False, 'error': str(e)}
            rid = resource_id(result)
            with self.lock:
                self.held[rid] = {'kind': kind, 'what': what, 'failed': ''}
            self._call('load ' + kind, t0, True)
        return dict(answer(result), ok=True, id=rid)

    def load_sensor(self, sensor_type: str, keys: List[str]) -> dict:
        return self._load('sensor', sensor_type,
                          lambda: self.sensors.start_sensor(sensor_type, output_topics=keys, on_status=self._on_status),
                          lambda r: r.resource_id, lambda r: {'sensor': r.sensor_name})

    def load_throttle(self, topic: str, rate: float) -> dict:
        """A process of its own: ``topic`` throttled to ``rate`` Hz on ``<topic>_throttled`` (equal requests
        share one process)."""
        args = 'messages %s %g %s_throttled' % (topic, rate, topic)
        return self._load('process', args,
                          lambda: self.processes.load_command(THROTTLE, args, on_status=self._on_status),
                          lambda r: r.trr.resource_id, lambda r: {'pid': r.pid})

    def track_object(self, name: str) -> dict:
        """An object tracked by the robot's Context Manager (its tracker reads a sensor's data)."""
        return self._load('tracked', name, lambda: self.context.track_object(name, on_status=self._on_status),
                          lambda r: r.resource_id, lambda r: {'tracker': r.tracker_name, 'topic': r.topic})

    def show_display(self, display_type: str, topic: str) -> dict:
        """A display of the robot's ``topic`` (relative to its namespace) on the station's screen."""
        if self.screen is None:
            return {'ok': False, 'error': 'this client has no station (no ~station_namespace)'}
        full = '/%s/%s' % (self.namespace, topic)
        return self._load('display', '%s %s' % (display_type, full),
                          lambda: self.screen.show(display_type, full, on_status=self._on_status),
                          lambda r: r.trr.resource_id, lambda r: {'display': r.display_name})

    # -- motion (history 5) --------------------------------------------------------------------------------------
    def _held_robot(self, feature: str) -> Optional[int]:
        with self.lock:
            return next((rid for rid, h in sorted(self.held.items())
                         if h['kind'] == 'robot' and h['what'] == feature and not h['failed']), None)

    def _robot(self, feature: str):
        """The robot's ``feature`` this client holds (loaded now if it holds none that works): (id, info), or
        an answer that says why not."""
        rid = self._held_robot(feature)
        if rid is not None:
            return rid, self.robot_info[rid]
        try:
            info = self.robots.robot_with(feature)
        except (OSError, ValueError, LookupError) as e:
            return None, {'ok': False, 'error': 'no robot with %s: %s' % (feature, e)}

        def load():
            loaded = self.robots.load_robot([feature], robot_name=info['name'], on_status=self._on_status)
            self.robot_info[loaded.resource_id] = info      # before the load is acknowledged (held)
            return loaded
        answer = self._load('robot', feature, load, lambda r: r.resource_id, lambda r: {'robot': r.robot_name})
        if not answer['ok']:
            return None, answer
        return answer['id'], info

    def _release_robot(self, resource_id: int) -> None:
        """A robot is released as a motion action releases it: its motions let go first."""
        if self.motion is not None:
            self.motion.releasing(resource_id)
        self.robots.release(resource_id)

    def navigate(self, x: float, y: float, yaw: float, frame: str) -> dict:
        rid, info = self._robot('navigation')
        if rid is None:
            return info
        return self.motion.navigate(rid, info, x, y, yaw, frame)

    def grip(self, gap: float, effort: float) -> dict:
        rid, info = self._robot('gripper')
        if rid is None:
            return info
        return self.motion.grip(rid, info, gap, effort)

    def servo(self, arm: str, source: str, offset: List[float], scale: float, seconds: float) -> dict:
        rid, info = self._robot('manipulation')
        if rid is None:
            return info
        if arm not in info.get('arm_frames', {}):
            return {'ok': False, 'error': '%s has no arm %r' % (info['name'], arm)}
        if source == 'path':
            return self.motion.servo_path(rid, info, arm, tuple(offset), seconds)
        with self.lock:
            hand = next((rid for rid, h in sorted(self.held.items())
                         if h['kind'] == 'sensor' and h['what'] == HAND_TYPE and not h['failed']), None)
        topic = self.hand_topics.get(hand)
        if topic is None:
            answer = self._load('sensor', HAND_TYPE,
                                lambda: self.sensors.start_sensor(HAND_TYPE, output_topics=[HAND_KEY],
                                                                  on_status=self._on_status),
                                lambda r: r.resource_id, lambda r: {'topic': r.topic(HAND_KEY)})
            if not answer['ok']:
                return answer
            topic = self.hand_topics[answer['id']] = answer['topic']
        return self.motion.servo_hand(rid, info, arm, topic, scale, seconds)

    def arm_goal(self, arm: str, offsets: List[float], speed: float) -> dict:
        rid, info = self._robot('manipulation')
        if rid is None:
            return info
        if arm not in info.get('arm_frames', {}):
            return {'ok': False, 'error': '%s has no arm %r' % (info['name'], arm)}
        return self.motion.arm_goal(rid, info, arm, offsets, speed)

    def cancel_motion(self, pick: int) -> dict:
        return self.motion.cancel(pick)

    def unload(self, resource_id: int) -> dict:
        t0 = time.monotonic()
        with self.lock:
            kind = self.held.get(resource_id, {}).get('kind', 'sensor')
        with self._under_way('unload', kind, resource_id):
            try:
                self.releases[kind](resource_id)
                ok, error = True, ''
            except TemotoError as e:
                ok, error = False, str(e)
            with self.lock:
                self.held.pop(resource_id, None)     # released here whatever the owner answered (it is owed)
                self.failed_heard.pop(resource_id, None)
                self.robot_info.pop(resource_id, None)
                self.hand_topics.pop(resource_id, None)
            self._call('unload ' + kind, t0, ok)
        return {'ok': ok, 'error': error}

    @contextlib.contextmanager
    def _under_way(self, op: str, kind: str, resource_id: int = 0) -> Iterator[None]:
        """A call listed as under way while it runs: it ends (however it ends) after what it held changed."""
        with self.lock:
            self._calls_started += 1
            call = self._calls_started
            self.pending[call] = {'op': op, 'kind': kind, 'id': resource_id}
        try:
            yield
        finally:
            with self.lock:
                self.pending.pop(call, None)

    def _call(self, op: str, t0: float, ok: bool) -> None:
        with self.lock:
            took = time.monotonic() - t0
            seen = self.calls.setdefault(op, {'count': 0, 'failed': 0, 'max_s': 0.0})
            seen['count'] += 1
            seen['failed'] += 0 if ok else 1
            seen['max_s'] = max(seen['max_s'], took)

    def unexpected_error(self, line: bytes, err: Exception) -> dict:
        """An operation raised what no caller is told to expect: kept for the checker, and answered."""
        text = '%r raised %s: %s' % (line[:200], type(err).__name__, err)
        rospy.logerr('%s: %s', NODE_NAME, text)
        with self.lock:
            self.unexpected.append(text)
        return {'ok': False, 'error': text}

    def state(self) -> dict:
        with self.lock:
            return {'node': rospy.get_name(), 'registrar': self.sensors.rr.name, 'pid': os.getpid(),
                    'held': {str(k): dict(v) for k, v in self.held.items()},
                    'failed_heard': {str(k): v for k, v in self.failed_heard.items()},
                    'recent_statuses': list(self.recent), 'calls': {op: dict(v) for op, v in self.calls.items()},
                    'unexpected': list(self.unexpected), 'pending': list(self.pending.values())}

    def handle(self, cmd: dict) -> dict:
        op = cmd.get('op')
        if op == 'load_sensor':
            return self.load_sensor(str(cmd['type']), [str(k) for k in cmd['keys']])
        if op == 'load_process':
            return self.load_throttle(str(cmd['topic']), float(cmd['rate']))
        if op == 'track_object':
            return self.track_object(str(cmd['object']))
        if op == 'show_display':
            return self.show_display(str(cmd['type']), str(cmd['topic']))
        if op == 'unload':
            return self.unload(int(cmd['id']))
        if op in ('navigate', 'grip', 'servo', 'arm_goal', 'cancel_motion') and self.motion is None:
            return {'ok': False, 'error': 'this client has no motion journal (~motion_journal)'}
        if op == 'navigate':
            return self.navigate(float(cmd['x']), float(cmd['y']), float(cmd['yaw']), str(cmd['frame']))
        if op == 'grip':
            return self.grip(float(cmd['gap']), float(cmd['effort']))
        if op == 'servo':
            return self.servo(str(cmd['arm']), str(cmd['source']), [float(v) for v in cmd['offset']],
                              float(cmd['scale']), float(cmd['seconds']))
        if op == 'arm_goal':
            return self.arm_goal(str(cmd['arm']), [float(v) for v in cmd['offsets']], float(cmd['speed']))
        if op == 'cancel_motion':
            return self.cancel_motion(int(cmd['pick']))
        if op == 'state':
            return self.state()
        return {'ok': False, 'error': 'unknown op %r: load_sensor, load_process, track_object, show_display, '
                                      'navigate, grip, servo, arm_goal, cancel_motion, unload or state' % (op,)}


def main() -> None:
    init_node(NODE_NAME)
    namespace = params.text('temoto_namespace', 'temoto', empty=False)
    socket_path = params.text('control_socket', '', empty=False)
    client = ChaosClient(namespace, params.text('station_namespace', ''), params.text('motion_journal', ''))
    server = control_socket.serve(socket_path, client.handle, 'chaos-control', client.unexpected_error)
    try:
        spin()
    finally:
        server.shutdown()
        client.sensors.shutdown()
