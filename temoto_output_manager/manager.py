"""The Output Manager: displays in the operator's RViz as Resource Registrar resources.

Architecture kept from the original: RViz is a
process started through the ER Manager, and every display resource holds a
reference to it. Concretely, ``load_rviz_plugin``'s load callback

1. maps the abstract type to an RViz class (unknown types are refused with the
   list of known ones) and checks topic and config before starting anything;
2. makes a nested ``load_process`` call (temoto_er_manager, package
   temoto_output_manager, executable rviz_host). The RR links it to the display
   resource: equal requests share one host, the host is unloaded in cascade
   when the last display goes, and the host's FAILED (a crash) is forwarded to
   every display resource automatically;
3. asks the host to add the display.

A crashed host is remembered as dead, so that unloading a display of the dead
host never removes a same-named display of the next host.

With a journal (``~journal``) the manager survives its own restart while the host
keeps running (the ER Manager holds it): each display's name and host are kept
in the journal, :meth:`OutputManager._recover` checks that the display is still
in the host, and ``rr.resume()`` asks the ER Manager whether the host still runs
(one that died meanwhile reaches the displays' consumers as FAILED).
"""
from __future__ import annotations

import json
import shlex
import threading
from typing import Callable, Dict, Optional, Tuple

import rospy

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_core.rr import ResourceRegistrar, StatusEvent

from temoto_er_manager.contract import LOAD_PROCESS, LOAD_PROCESS_TYPE, RR_NAME as ER_MANAGER
from temoto_output_manager.contract import LOAD_RVIZ_PLUGIN, LOAD_RVIZ_PLUGIN_TYPE

from . import display_config
from .display_types import DEFAULT_CONFIG, UnknownDisplayType, check_topic_name, needs_topic, rviz_class_for
from .host_client import RvizHostClient, RvizHostError

HOST_PACKAGE = 'temoto_output_manager'
HOST_EXECUTABLE = 'rviz_host'
HOST_NODE = 'rviz_host'
DISPLAY_KEY = 'display/%d'      # owner state: a display's name and host, by internal id


def _error(code: ErrorCode, message: str) -> TemotoError:
    return TemotoError(code, Subsystem.OUTPUT_MANAGER, message)


def host_args(namespace: str, params: Dict[str, object]) -> str:
    """The RViz host's command line: its node name and private params. The ER Manager splits it with shlex,
    so each argument is quoted: a value with a space (a list of robots) stays one argument."""
    args = ['__name:=%s' % HOST_NODE, '_temoto_namespace:=%s' % namespace]
    args += ['_%s:=%s' % (k, v) for k, v in sorted(params.items())]
    return ' '.join(shlex.quote(arg) for arg in args)


class OutputManager:
    """Serves ``/<ns>/temoto_output_manager/load_rviz_plugin``."""

    def __init__(self, rr: ResourceRegistrar, host_params: Optional[Dict[str, object]] = None,
                 host_ready_timeout: float = 20.0, host_start_attempts: int = 2,
                 client_factory: Callable[[str], RvizHostClient] = RvizHostClient) -> None:
        self.rr = rr
        self.namespace = rr.namespace
        self.host_params = dict(host_params or {})
        self.host_ready_timeout = host_ready_timeout
        self.host_start_attempts = max(1, int(host_start_attempts))
        self.host_node = '/%s/%s' % (self.namespace, HOST_NODE)
        self.client = client_factory(self.host_node)
        self._lock = threading.Lock()
        self._displays: Dict[int, Tuple[str, int]] = {}   # internal id -> (display name, host pid)
        self._dead_hosts: set = set()                     # pids of hosts that failed
        self._host_pid_by_local: Dict[int, int] = {}
        self._host_failures: Dict[int, str] = {}          # local id of a host resource -> why it failed
        self._records = {int(k.split('/')[1]): json.loads(v) for k, v in rr.owner_state().items()
                         if k.startswith('display/')}
        # one callback for every host held, also the one a restart brings back
        rr.register_status_callback(self._on_host_status)
        rr.add_server(LOAD_RVIZ_PLUGIN, LOAD_RVIZ_PLUGIN_TYPE, self.load_cb, self.unload_cb, recover=self._recover)
        for stale in self._records:
            rr.drop_owner_state(DISPLAY_KEY % stale)
        self._records.clear()
        rr.resume()

    # ------------------------------------------------------------------ the host process
    def _host_request(self):
        return LOAD_PROCESS_TYPE._request_class(action='ros_execute', ros_namespace='/' + self.namespace,
                                                package_name=HOST_PACKAGE, executable=HOST_EXECUTABLE,
                                                args=host_args(self.namespace, self.host_params))

    def _on_host_status(self, ev: StatusEvent) -> None:
        # The RR forwards a FAILED to the display resources by itself; here only remember the host is gone
        # (and why: a load still waiting for this host to come up fails at once with the reason).
        if ev.code == ResourceStatus.FAILED:
            with self._lock:
                self._host_failures[ev.resource_id] = ev.message
                pid = self._host_pid_by_local.get(ev.resource_id)
                if pid is not None:
                    self._dead_hosts.add(pid)
            rospy.logwarn('%s: the RViz host failed: %s', self.rr.prefix, ev.message)

    def _start_or_share_host(self) -> Tuple[int, int]:
        """(local id, pid) of a host whose services answer: the running one, or a new one.

        A host that dies while starting (Mesa's llvmpipe segfaults now and then in
        the first frames under load) is released and started once more; the
        reason of the last failure, with the host's log tail, is the error.
        """
        for attempt in range(1, self.host_start_attempts + 1):
            try:
                resp = self.rr.call(ER_MANAGER, LOAD_PROCESS, self._host_request())
            except TemotoError as e:     # died before it registered at the master: the same start-up crash
                if e.origin.code != ErrorCode.PROCESS_STOPPED or attempt == self.host_start_attempts:
                    raise
                rospy.logwarn('%s: the RViz host died while starting: %s; starting another one (attempt %d of %d)',
                              self.rr.prefix, e, attempt + 1, self.host_start_attempts)
                continue
            local_id = resp.trr.resource_id
            with self._lock:
                self._host_pid_by_local[local_id] = resp.pid

            def failed(local_id=local_id) -> Optional[str]:
                with self._lock:
                    return self._host_failures.get(local_id)
            try:
                self.client.wait_ready(self.host_ready_timeout, failed=failed)
                return local_id, resp.pid
            except RvizHostError as e:
                if failed() is None or attempt == self.host_start_attempts:
                    raise _error(ErrorCode.DISPLAY_FAIL, str(e)) from None
                rospy.logwarn('%s: %s; starting another RViz host (attempt %d of %d)', self.rr.prefix, e,
                              attempt + 1, self.host_start_attempts)
                try:
                    self.rr.unload(local_id)
                except TemotoError as err:
                    rospy.logwarn('%s: releasing the failed RViz host: %s', self.rr.prefix, err)
        raise AssertionError('unreachable')

    # ------------------------------------------------------------------ RR callbacks
    def load_cb(self, req, resp) -> None:
        try:
            cls = rviz_class_for(req.type)
        except UnknownDisplayType as e:
            raise _error(ErrorCode.BAD_REQUEST, str(e)) from None
        topic = req.topic.strip()
        if needs_topic(cls) and not topic:
            raise _error(ErrorCode.BAD_REQUEST, "display type '%s' needs a topic; none was given" % req.type)
        try:
            if topic:
                check_topic_name(topic)
            config = display_config.with_defaults(DEFAULT_CONFIG.get(cls, {}), req.config)
        except ValueError as e:
            raise _error(ErrorCode.BAD_REQUEST, str(e)) from None
        host_id, pid = self._start_or_share_host()
        name = req.name.strip() or ('%s %s' % (req.type.strip(), topic)).strip()
        try:
            try:
                shown = self.client.add_display(cls, topic, name=name, config=config)
            except RvizHostError as e:
                if 'already exists' not in str(e) or req.name.strip():
                    raise
                shown = self.client.add_display(cls, topic, name='%s #%d' % (name, resp.trr.resource_id),
                                                config=config)
        except RvizHostError as e:
            raise _error(ErrorCode.DISPLAY_FAIL, str(e)) from None
        with self._lock:
            self._displays[resp.trr.resource_id] = (shown, pid)
        self.rr.put_owner_state(DISPLAY_KEY % resp.trr.resource_id,
                                json.dumps({'name': shown, 'host_pid': pid, 'host_id': host_id}))
        resp.display_name = shown
        rospy.loginfo("%s: showing %s on %s as '%s'", self.rr.prefix, req.type, topic or '-', shown)

    def unload_cb(self, req, resp) -> None:
        self.rr.drop_owner_state(DISPLAY_KEY % resp.trr.resource_id)
        with self._lock:
            name, pid = self._displays.pop(resp.trr.resource_id, (resp.display_name, None))
            dead = pid in self._dead_hosts
        if dead:
            return      # its host is gone, and with it the display
        try:
            self.client.remove_display(name)
        except RvizHostError as e:
            rospy.logwarn("%s: could not remove display '%s': %s", self.rr.prefix, name, e)

    def _recover(self, req, resp) -> None:
        """A display the previous incarnation showed: still in the host? (The host runs on; whether it
        still does is asked of the ER Manager in ``resume``.)"""
        rid = resp.trr.resource_id
        record = self._records.pop(rid, None)
        if record is None:
            raise _error(ErrorCode.DISPLAY_FAIL, 'the journal has no record of display %r' % resp.display_name)
        try:
            shown = self.client.display_names()
        except RvizHostError as e:
            raise _error(ErrorCode.DISPLAY_FAIL, "display '%s': %s" % (record['name'], e)) from None
        if record['name'] not in shown:
            raise _error(ErrorCode.DISPLAY_FAIL, "display '%s' is not in the RViz host any more (it shows: %s)"
                         % (record['name'], ', '.join(shown) or 'nothing'))
        with self._lock:
            self._displays[rid] = (record['name'], record['host_pid'])
            self._host_pid_by_local[record['host_id']] = record['host_pid']
        rospy.loginfo("%s: took display '%s' back after a restart", self.rr.prefix, record['name'])

    def displays(self) -> Dict[int, str]:
        with self._lock:
            return {rid: name for rid, (name, _) in self._displays.items()}
