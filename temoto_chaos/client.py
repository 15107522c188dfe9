"""A chaos client: a registrar of its own in its own process, loading and unloading sensors and processes
when told.

The runner drives it over a Unix socket (one JSON object per line, one answer per line), so it reaches the
client whatever the ROS graph is doing. The client acknowledges what the Sensor Manager acknowledged, and
keeps, for the checker, what a real consumer would know: the resources it holds, every status it heard
for them, and how long each call took against its deadline. It sets no failure policy of its own beyond
recording: a FAILED resource stays held (failed) until the runner unloads it, as an action's would until
its policy runs.
"""
from __future__ import annotations

import collections
import json
import os
import socketserver
import threading
import time
from typing import Deque, Dict, List

import rospy

from temoto_core.errors import TemotoError
from temoto_core.node import init_node, spin
from temoto_core.rr import StatusEvent
from temoto_er_manager.interface import ERManagerInterface
from temoto_sensor_manager.interface import SensorManagerInterface

NODE_NAME = 'chaos_client'     # the runner names each incarnation (__name:=chaos_client_<client>_<generation>)
RECENT_STATUSES = 20
THROTTLE = '/usr/lib/topic_tools/throttle'     # the process a client runs (the chaos ER config allows it)


class ChaosClient:
    """The state a consumer knows, and the operations the runner asks of it."""

    def __init__(self, namespace: str) -> None:
        self.sensors = SensorManagerInterface(namespace=namespace)
        self.processes = ERManagerInterface(rr=self.sensors.rr, namespace=namespace)     # one registrar
        self.lock = threading.Lock()
        self.held: Dict[int, dict] = {}        # local id -> {'kind', 'type', 'sensor', 'failed': message or ''}
        # what the checker needs stays bounded over a history of any length: the FAILED heard for what is
        # still held, the last statuses (to read a report), and per operation its count and slowest call
        self.failed_heard: Dict[int, str] = {}     # local id -> the FAILED's message, until it is unloaded
        self.recent: Deque[dict] = collections.deque(maxlen=RECENT_STATUSES)
        self.calls: Dict[str, dict] = {}           # op -> {'count', 'failed', 'max_s'}: held to its deadline
        self.unexpected: List[str] = []            # a call that raised something other than a TemotoError

    def _on_status(self, ev: StatusEvent) -> None:
        with self.lock:
            self.recent.append({'id': ev.resource_id, 'code': ev.code.name, 'message': ev.message})
            if ev.failed:
                self.failed_heard[ev.resource_id] = ev.message or 'FAILED'
                if ev.resource_id in self.held:
                    self.held[ev.resource_id]['failed'] = ev.message or 'FAILED'

    def load_sensor(self, sensor_type: str, keys: List[str]) -> dict:
        t0 = time.monotonic()
        try:
            result = self.sensors.start_sensor(sensor_type, output_topics=keys, on_status=self._on_status)
        except TemotoError as e:
            self._call('load', t0, False)
            return {'ok': False, 'error': str(e)}
        self._call('load', t0, True)
        with self.lock:
            self.held[result.resource_id] = {'kind': 'sensor', 'type': sensor_type, 'sensor': result.sensor_name,
                                             'failed': ''}
        return {'ok': True, 'id': result.resource_id, 'sensor': result.sensor_name}

    def load_throttle(self, topic: str, rate: float) -> dict:
        """A process of its own: ``topic`` throttled to ``rate`` Hz on ``<topic>_throttled`` (equal requests
        share one process)."""
        t0 = time.monotonic()
        args = 'messages %s %g %s_throttled' % (topic, rate, topic)
        try:
            result = self.processes.load_command(THROTTLE, args, on_status=self._on_status)
        except TemotoError as e:
            self._call('load', t0, False)
            return {'ok': False, 'error': str(e)}
        self._call('load', t0, True)
        rid = result.trr.resource_id
        with self.lock:
            self.held[rid] = {'kind': 'process', 'type': 'throttle', 'sensor': args, 'failed': ''}
        return {'ok': True, 'id': rid, 'pid': result.pid}

    def unload(self, resource_id: int) -> dict:
        t0 = time.monotonic()
        with self.lock:
            kind = self.held.get(resource_id, {}).get('kind', 'sensor')
        try:
            if kind == 'process':
                self.processes.unload(resource_id)
            else:
                self.sensors.stop_sensor(resource_id)
            ok, error = True, ''
        except TemotoError as e:
            ok, error = False, str(e)
        self._call('unload', t0, ok)
        with self.lock:
            self.held.pop(resource_id, None)     # released here whatever the owner answered (it is owed)
            self.failed_heard.pop(resource_id, None)
        return {'ok': ok, 'error': error}

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
                    'unexpected': list(self.unexpected)}

    def handle(self, cmd: dict) -> dict:
        op = cmd.get('op')
        if op == 'load_sensor':
            return self.load_sensor(str(cmd['type']), [str(k) for k in cmd['keys']])
        if op == 'load_process':
            return self.load_throttle(str(cmd['topic']), float(cmd['rate']))
        if op == 'unload':
            return self.unload(int(cmd['id']))
        if op == 'state':
            return self.state()
        return {'ok': False, 'error': 'unknown op %r: load_sensor, load_process, unload or state' % (op,)}


class _Handler(socketserver.StreamRequestHandler):
    def handle(self) -> None:
        for line in self.rfile:
            try:
                answer = self.server.client.handle(json.loads(line))
            except (ValueError, KeyError, TypeError) as e:
                answer = {'ok': False, 'error': 'bad command %r: %s' % (line[:200], e)}
            except Exception as e:      # an interface that raised something other than a TemotoError: reported
                answer = self.server.client.unexpected_error(line, e)
            self.wfile.write(json.dumps(answer).encode() + b'\n')
            self.wfile.flush()


class _Server(socketserver.ThreadingMixIn, socketserver.UnixStreamServer):
    daemon_threads = True


def main() -> None:
    init_node(NODE_NAME)
    namespace = str(rospy.get_param('~temoto_namespace', 'temoto'))
    socket_path = str(rospy.get_param('~control_socket'))
    client = ChaosClient(namespace)
    server = _Server(socket_path, _Handler)
    server.client = client
    threading.Thread(target=server.serve_forever, name='chaos-control', daemon=True).start()
    try:
        spin()
    finally:
        server.shutdown()
        client.sensors.shutdown()
