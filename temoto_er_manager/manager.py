"""The ER Manager's logic: a Resource Registrar server ``load_process`` over a ProcessSupervisor.

Load = validate, resolve, spawn, and wait until the process *really* started
(alive, and for ROS nodes registered at the master by the very process we
started), so the response carries a real pid. Equal requests share one process
(the registrar calls ``_load`` once). A child that exits while held is
reported FAILED to every consumer at once, with its exit reason, output tail
and command; an unload is never reported as a failure.

Processes are not recovered across a manager restart: children die with the
manager (``death_signal``), see :mod:`temoto_er_manager.supervisor`.
"""
from __future__ import annotations

import json
import threading
import time
from typing import Optional

import rosgraph
import rospy

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_core.srv import GetRegistry, GetRegistryResponse
from temoto_core.rr import ResourceRegistrar

from . import master
from .policy import ERConfig, RequestRefused, validate_request
from .resolve import Resolver
from .supervisor import (ExitInfo, ManagedProcess, ProcessExitedEarly, ProcessSupervisor, ReadyTimeout,
                         StartCancelled, SupervisorError)
from temoto_er_manager.srv import LoadProcess

NAME = 'temoto_er_manager'
SERVER = 'load_process'


def load_config(params: dict) -> ERConfig:
    """ERConfig from the node's private parameters (unrelated keys such as ``temoto_namespace`` are ignored)."""
    from dataclasses import fields
    known = {f.name for f in fields(ERConfig)}
    return ERConfig.from_dict({k: v for k, v in params.items() if k in known})


class ERManager:
    """Serves ``/<ns>/temoto_er_manager/load_process`` and ``.../processes`` (JSON of the supervisor's children)."""

    def __init__(self, config: ERConfig, rr: Optional[ResourceRegistrar] = None, namespace: Optional[str] = None):
        self.config = config
        self.rr = rr or ResourceRegistrar(NAME, namespace=namespace, subsystem=Subsystem.ER_MANAGER)
        self.master_uri = rosgraph.get_master_uri()
        self.supervisor = ProcessSupervisor(self._on_exit, sigint_grace=config.sigint_grace,
                                            sigterm_grace=config.sigterm_grace,
                                            death_signal=config.death_signal_number(),
                                            tail_lines=config.log_tail_lines)
        self.resolver = Resolver(config)
        self._lock = threading.Lock()
        self._by_id: dict[int, ManagedProcess] = {}     # internal resource id -> its process
        self._loading: set[int] = set()
        self._cancelled: set[int] = set()                # unloaded before their process existed
        self._closing = False
        self.rr.add_server(SERVER, LoadProcess, self._load, self._unload)
        self._processes_srv = rospy.Service('/%s/%s/processes' % (self.rr.namespace, NAME), GetRegistry,
                                            lambda _req: GetRegistryResponse(json=self.processes_json()))
        rospy.loginfo('%s: ready (sys_execute allowlist: %s; package allowlist: %s; logs in %s)', NAME,
                      config.sys_allowlist or 'none', config.package_allowlist or 'all', self.resolver.log_dir)

    # -- load / unload ---------------------------------------------------------------------------

    def _load(self, req, res) -> None:
        rid = res.trr.resource_id
        client = req.trr.client_name or '?'
        try:
            lreq = validate_request(req.action, req.ros_namespace, req.package_name, req.executable, req.args,
                                    self.config, base_ns=rospy.get_namespace())
            spec = self.resolver.resolve(lreq, name_taken=self._name_taken)
        except RequestRefused as e:
            rospy.logwarn('%s: refused load_process from %s (%s %s %s %r): %s', NAME, client, req.action,
                          req.package_name, req.executable, req.args, e)
            raise
        with self._lock:
            if self._closing:
                raise TemotoError(ErrorCode.SHUTDOWN, Subsystem.ER_MANAGER, 'the ER Manager is shutting down')
            self._loading.add(rid)
        proc = None
        try:
            try:
                proc = self.supervisor.start(spec)
            except SupervisorError as e:
                raise TemotoError(ErrorCode.EXECUTABLE_NOT_FOUND, Subsystem.ER_MANAGER, str(e)) from None
            proc.resource_id = rid
            with self._lock:
                cancelled = rid in self._cancelled or self._closing
                self._by_id[rid] = proc
            if cancelled:
                self.supervisor.stop(proc)
                raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER,
                                  '%s was unloaded while it was starting' % spec.label)
            self._wait_started(proc)
        except BaseException:
            if proc is not None:
                self.supervisor.stop(proc)
                self.supervisor.forget(proc)
                with self._lock:
                    self._by_id.pop(rid, None)
            raise
        finally:
            with self._lock:
                self._loading.discard(rid)
                self._cancelled.discard(rid)
        res.pid = proc.pid
        res.log_path = spec.log_path
        rospy.loginfo('%s: started %s for %s: pid %d, log %s', NAME, spec.label, client, proc.pid, spec.log_path)

    def _wait_started(self, proc: ManagedProcess) -> None:
        spec = proc.spec
        if spec.node_names:
            launch = spec.argv[1:2] and spec.argv[1].endswith('launch_runner.py')

            def registered(p: ManagedProcess) -> bool:
                return all(master.node_is_ours(self.master_uri, n, [p.pid], parent=p.pid if launch else None)
                           for n in spec.node_names)
            check, timeout = registered, self.config.registration_timeout
        else:                                 # sys_execute, or a launch file of anonymous nodes only
            check, timeout = None, self.config.sys_settle_time
        try:
            self.supervisor.wait_ready(proc, check, timeout, self.config.ready_poll_interval)
        except ProcessExitedEarly as e:
            raise TemotoError(ErrorCode.PROCESS_STOPPED, Subsystem.ER_MANAGER, str(e)) from None
        except ReadyTimeout as e:
            raise TemotoError(ErrorCode.TIMEOUT, Subsystem.ER_MANAGER,
                              '%s: node(s) %s did not register with the master within %.1f s; last output:\n%s'
                              % (e, ', '.join(spec.node_names), timeout,
                                 _tail(spec.log_path, self.config.log_tail_lines))) from None
        except StartCancelled as e:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER, str(e)) from None

    def _unload(self, req, res) -> None:
        rid = res.trr.resource_id
        with self._lock:
            proc = self._by_id.pop(rid, None)
            if proc is None and rid in self._loading:
                self._cancelled.add(rid)      # its process is not spawned yet: _load stops it
        if proc is None:
            return
        info = self.supervisor.stop(proc)
        self.supervisor.forget(proc)
        rospy.loginfo('%s: unloaded %s (pid %d, %s)', NAME, proc.spec.label, proc.pid, info.reason)

    def _name_taken(self, full_name: str) -> bool:
        for p in self.supervisor.processes():
            if p.alive and full_name in p.spec.node_names:
                return True
        try:
            uri = master.lookup_node(self.master_uri, full_name)
        except OSError:
            return False
        # a stale registration (a node that was SIGKILLed never unregisters) does not count
        return uri is not None and master.node_pid(uri) is not None

    # -- failures ----------------------------------------------------------------------------------

    def _on_exit(self, proc: ManagedProcess, info: ExitInfo) -> None:
        rid = getattr(proc, 'resource_id', None)
        if rid is None or not proc.ready or self._closing:
            return                            # failed while loading: _load reports it to the caller
        message = '%s: %s' % (proc.spec.label, info.message())
        rospy.logerr('%s: %s', NAME, message)
        err = TemotoError(ErrorCode.PROCESS_STOPPED, Subsystem.ER_MANAGER, message)
        try:
            self.rr.send_status(rid, ResourceStatus.FAILED, message, error_stack=err.stack)
        except Exception as e:                # e.g. the resource was unloaded meanwhile
            rospy.logwarn('%s: could not report the exit of pid %d: %s', NAME, proc.pid, e)

    # -- introspection and shutdown ------------------------------------------------------------------

    def processes_json(self) -> str:
        rows = []
        for p in self.supervisor.processes():
            row = p.snapshot()
            row['resource_id'] = getattr(p, 'resource_id', None)
            rows.append(row)
        return json.dumps({'manager': NAME, 'time': time.time(), 'processes': rows}, sort_keys=True)

    def shutdown(self) -> None:
        """Unload everything (no FAILED is sent for it) and stop every child."""
        with self._lock:
            if self._closing:
                return
            self._closing = True
        try:
            self.rr.shutdown()
        except Exception as e:
            rospy.logwarn('%s: registrar shutdown: %s', NAME, e)
        self.supervisor.shutdown()
        self._processes_srv.shutdown()


def _tail(path: str, lines: int) -> str:
    from .supervisor import read_tail
    return read_tail(path, lines)
