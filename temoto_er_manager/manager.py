"""The ER Manager's logic: a Resource Registrar server ``load_process`` over a ProcessSupervisor.

Load = validate, resolve, spawn, and wait until the process *really* started
(alive, and for ROS nodes registered at the master by the very process we
started), so the response carries a real pid. A launch file is one resource of
several processes, one per node (:mod:`temoto_er_manager.launchfile`): its load
returns once every node is registered, and any node's exit fails the resource
at once (the message names the node), after which its other nodes are stopped. Equal requests share one process
(the registrar calls ``_load`` once). A child that exits while held is
reported FAILED to every consumer at once, with its exit reason, output tail
and command; an unload is never reported as a failure.

Across a restart: without a journal, children die with the manager
(``death_signal``). With one (``~journal``), children outlive it on a leash
(:mod:`temoto_er_manager.leash`); each resource's processes (pid and start time)
are kept in the journal, and the next incarnation adopts those that still run
(:meth:`ERManager._recover`). A resource with a process that died meanwhile is
reported FAILED to its consumers by the registrar, and a child that no resource
claims is stopped. With ``preload_python`` Python nodes are forked from a zygote
that has their common imports done (:mod:`temoto_er_manager.zygote`).
"""
from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import fields
from typing import List, Optional

import psutil
import rosgraph
import rospy

from temoto_core.errors import ErrorCode, Subsystem, TemotoError
from temoto_core.msg import ResourceStatus
from temoto_core.srv import GetRegistry, GetRegistryResponse
from temoto_core.rr import ResourceRegistrar
from temoto_core.rr.settings import journal_param

from temoto_core import master_lookup as master, master_rejoin
from temoto_core.process_group import start_ticks
from temoto_er_manager.contract import LOAD_PROCESS, LOAD_PROCESS_TYPE, RR_NAME as NAME
from .policy import ERConfig, RequestRefused, validate_request
from temoto_core.processes import processes_with_env
from .leash import OWNER_ENV, Leash, LeashError, address_for
from .resolve import Plan, Resolver
from .resource import Resource
from .supervisor import (ExitInfo, ManagedProcess, ProcessExitedEarly, ProcessSpec, ProcessSupervisor,
                         ReadyTimeout, SpawnerStuck, StartCancelled, SupervisorError)
from .supervisor import read_tail

PROCESS_KEY = 'process/%d'            # owner state: the processes of a loaded resource, by internal id



def load_config(params: dict) -> ERConfig:
    """ERConfig from the node's private parameters (unrelated keys such as ``temoto_namespace`` are ignored)."""
    known = {f.name for f in fields(ERConfig)}
    return ERConfig.from_dict({k: v for k, v in params.items() if k in known})


class ERManager:
    """Serves ``/<ns>/temoto_er_manager/load_process`` and ``.../processes`` (JSON of the supervisor's children)."""

    def __init__(self, config: ERConfig, rr: Optional[ResourceRegistrar] = None, namespace: Optional[str] = None):
        self.config = config
        self.master_uri = rosgraph.get_master_uri()
        self.resolver = Resolver(config)
        stamp = '%s-%d' % (time.strftime('%Y%m%d-%H%M%S'), os.getpid())
        preload_log = os.path.join(self.resolver.log_dir, stamp + '-zygote.log')
        journal = rr.journal_path if rr is not None else journal_param()
        self.leash: Optional[Leash] = None
        leashed: list = []
        if journal:
            # before the registrar exists: a second manager on this journal is refused here, before it
            # advertises anything over the first one's services
            self.leash = Leash(address_for(journal), config.adoption_bound, config.sigint_grace,
                               config.sigterm_grace, os.path.join(self.resolver.log_dir, 'leash.log'),
                               on_restart=lambda text: rospy.logwarn('%s: %s', NAME, text))
            try:
                leashed = self.leash.attach()
            except LeashError as e:
                raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER, str(e)) from None
            # every child (the zygote's too) carries its owner: see _stop_unclaimed
            self.resolver.env[OWNER_ENV] = address_for(journal)
        self.rr = rr or ResourceRegistrar(NAME, namespace=namespace, subsystem=Subsystem.ER_MANAGER, journal=journal)
        self.supervisor = ProcessSupervisor(self._on_exit, sigint_grace=config.sigint_grace,
                                            sigterm_grace=config.sigterm_grace,
                                            death_signal=0 if self.leash else config.death_signal_number(),
                                            tail_lines=config.log_tail_lines,
                                            preload_modules=config.preload_modules if config.preload_python else None,
                                            preload_log=preload_log, preload_env=self.resolver.env,
                                            leash=self.leash)
        self._records = {int(k.split('/')[1]): json.loads(v) for k, v in self.rr.owner_state().items()
                         if k.startswith('process/')}
        self._lock = threading.Lock()
        self._names_lock = threading.Lock()              # held from choosing a request's node names to claiming them
        self._resources: dict[int, Resource] = {}       # internal resource id -> resource, loading or loaded
        # unloaded, its processes still being stopped (SIGINT, SIGTERM, SIGKILL, each with its grace): still
        # listed, so that no live process is ever missing from the list
        self._stopping: dict[int, Resource] = {}
        self._closing = False
        self.rr.add_server(LOAD_PROCESS, LOAD_PROCESS_TYPE, self._load, self._unload, recover=self._recover)
        self._stop_unclaimed(leashed)
        # before resume(): a registry that says it is done recovering speaks for a manager that answers in full
        self._processes_srv = rospy.Service('/%s/%s/processes' % (self.rr.namespace, NAME), GetRegistry,
                                            lambda _req: GetRegistryResponse(json=self.processes_json()))
        self.rr.resume()
        rospy.loginfo('%s: ready (sys_execute allowlist: %s; package allowlist: %s; logs in %s; Python nodes %s)',
                      NAME, config.sys_allowlist or 'none', config.package_allowlist or 'all', self.resolver.log_dir,
                      'forked from a zygote preloading ' + ', '.join(config.preload_modules)
                      if config.preload_python else 'started plainly')

    # -- load / unload ---------------------------------------------------------------------------

    def _load(self, req, res) -> None:
        rid = res.trr.resource_id
        client = req.trr.client_name or '?'
        # names are chosen and claimed under one lock: two requests naming the same node must not both
        # pass the check and then make the master shut one of them down
        with self._names_lock:
            try:
                lreq = validate_request(req.action, req.ros_namespace, req.package_name, req.executable, req.args,
                                        self.config, base_ns=rospy.get_namespace())
                plan = self.resolver.resolve(lreq, name_taken=self._name_taken)
                self._refuse_taken_names(plan)
                # what a dead node of these names left at the master goes first: the master would send the new
                # node's predecessor a shutdown, and a live node that has the dead one's port now would get it
                self._cleanup_master([n for spec in plan.specs for n in spec.node_names])
            except RequestRefused as e:
                rospy.logwarn('%s: refused load_process from %s (%s %s %s %r): %s', NAME, client, req.action,
                              req.package_name, req.executable, req.args, e)
                raise
            resource = Resource(rid, plan)
            with self._lock:
                if self._closing:
                    raise TemotoError(ErrorCode.SHUTDOWN, Subsystem.ER_MANAGER, 'the ER Manager is shutting down')
                self._resources[rid] = resource
        for warning in plan.warnings:
            rospy.logwarn('%s: %s', NAME, warning)
        try:
            self._set_params(plan)
            for spec in plan.specs:
                try:
                    proc = self.supervisor.start(spec)
                except SpawnerStuck as e:
                    raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER, str(e)) from None
                except SupervisorError as e:
                    raise TemotoError(ErrorCode.EXECUTABLE_NOT_FOUND, Subsystem.ER_MANAGER, str(e)) from None
                proc.resource = resource
                with resource.lock:
                    resource.procs.append(proc)
                    cancelled = resource.stopping        # an unload that came meanwhile missed this process
                if cancelled:
                    raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER,
                                      '%s was unloaded while it was starting' % plan.label)
            self._wait_started(resource)
        except BaseException:
            with resource.lock:
                resource.stopping = True
            self._stop_all(resource.procs)
            with self._lock:
                if self._resources.get(rid) is resource:
                    del self._resources[rid]
            raise
        res.pid = resource.pid
        res.log_path = plan.log_path
        self.rr.put_owner_state(PROCESS_KEY % rid, json.dumps(_record_of(resource)))
        rospy.loginfo('%s: started %s for %s: pid %s, log %s', NAME, plan.label, client,
                      ', '.join(str(p.pid) for p in resource.procs), plan.log_path)
        self._speak_for_nodes(resource.procs)

    def _set_params(self, plan) -> None:
        if not plan.params and not plan.clear_params:
            return
        try:
            master.set_params(self.master_uri, plan.clear_params, plan.params)
        except Exception as e:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER,
                              '%s: cannot set its parameters on the master: %s' % (plan.label, e)) from None

    def _wait_started(self, resource: Resource) -> None:
        """Every process started (for ROS nodes: registered by that very process), then ``resource.ready``."""
        procs = list(resource.procs)
        names = [n for p in procs for n in p.spec.node_names]
        if names:
            def registered(p: ManagedProcess) -> bool:
                # parent=: a node under a launch-prefix wrapper is the child of the process we started
                return all(master.node_is_ours(self.master_uri, n, [p.pid], parent=p.pid) for n in p.spec.node_names)
            check, timeout = registered, self.config.registration_timeout
        else:                                 # sys_execute
            check, timeout = None, self.config.sys_settle_time
        try:
            self.supervisor.wait_all_ready(procs, check, timeout, self.config.ready_poll_interval)
            with resource.lock:
                # a process that dies from here on is reported FAILED by _on_exit; one that died just before
                # was ignored there (not ready yet), so it must fail the load here
                dead = [p for p in procs if not p.alive]
                if not dead and not resource.stopping:
                    resource.ready = True
            if dead:
                info = dead[0].exit_info
                raise ProcessExitedEarly('process %d (%s) %s before it was ready; last output:\n%s'
                                         % (info.pid, info.command, info.reason, info.log_tail), info)
            if not resource.ready:
                raise StartCancelled('%s was unloaded while it was starting' % resource.label)
        except ProcessExitedEarly as e:
            raise TemotoError(ErrorCode.PROCESS_STOPPED, Subsystem.ER_MANAGER,
                              self._which(resource, e.exit_info.pid) + str(e)) from None
        except ReadyTimeout as e:
            late = [n for p in procs for n in p.spec.node_names if not p.ready]
            raise TemotoError(ErrorCode.TIMEOUT, Subsystem.ER_MANAGER,
                              '%s: node(s) %s did not register with the master within %.1f s; last output:\n%s'
                              % (e, ', '.join(late or names), timeout,
                                 _tail(resource.plan.log_path, self.config.log_tail_lines))) from None
        except StartCancelled as e:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER, str(e)) from None

    @staticmethod
    def _which(resource: Resource, pid: int) -> str:
        """'pkg/file.launch: node /x: ' for a launch file's process, '' for a single process."""
        if len(resource.procs) < 2 and not resource.plan.is_launch:
            return ''
        for p in resource.procs:
            if p.pid == pid:
                return '%s: node %s: ' % (resource.label, resource.node_of(p))
        return '%s: ' % resource.label

    def _unload(self, req, res) -> None:
        rid = res.trr.resource_id
        with self._lock:
            resource = self._resources.pop(rid, None)
            if resource is not None:
                self._stopping[rid] = resource
        self.rr.drop_owner_state(PROCESS_KEY % rid)
        if resource is None:
            return
        with resource.lock:
            resource.stopping = True          # a load still starting stops what it spawns from now on
            procs = list(resource.procs)
        try:
            infos = self._stop_all(procs)
        finally:
            with self._lock:
                self._stopping.pop(rid, None)
        rospy.loginfo('%s: unloaded %s (pid %s: %s)', NAME, resource.label,
                      ', '.join(str(p.pid) for p in procs) or 'none yet',
                      '; '.join(i.reason for i in infos) or 'its load stops it')

    def _stop_all(self, procs: list) -> list:
        """Stop processes in parallel (each SIGINT, SIGTERM, SIGKILL, reaped); their exit infos."""
        infos = [None] * len(procs)

        def stop(i, p):
            try:
                infos[i] = self.supervisor.stop(p)
            except Exception as e:            # never seen: SIGKILL did not end it
                rospy.logerr('%s: stopping pid %d failed: %s', NAME, p.pid, e)
            self.supervisor.forget(p)
        if len(procs) == 1:
            stop(0, procs[0])
        else:
            threads = [threading.Thread(target=stop, args=(i, p), daemon=True) for i, p in enumerate(procs)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
        return [i for i in infos if i is not None]

    def _refuse_taken_names(self, plan) -> None:
        """A node name (set by ``__name``, the namespace, or a launch file) that a live node or another
        managed process already has is refused: the master would shut the older node down."""
        taken = [n for spec in plan.specs for n in spec.node_names if self._name_taken(n)]
        if taken:
            raise RequestRefused('NAME_TAKEN', '%s: node name %s is already in use by a live node or another '
                                 'process of this manager; starting it would make the master shut that node '
                                 'down (choose another __name or namespace)' % (plan.label, ', '.join(taken)))

    def _name_taken(self, full_name: str) -> bool:
        with self._lock:
            resources = list(self._resources.values())
        for resource in resources:
            # starting, running or stopping: its nodes are (or are about to be) at the master
            if resource.state() != 'exited' and any(full_name in spec.node_names for spec in resource.plan.specs):
                return True
        try:
            # a stale registration (a node that was SIGKILLed never unregisters) does not count, even when its
            # port has been given to another node since, which then answers there
            return master.registration_alive(self.master_uri, full_name)
        except OSError:
            return False

    # -- recovery after a restart ---------------------------------------------------------------------

    def _recover(self, req, res) -> None:
        """A resource the previous incarnation served: adopt its processes, or raise if one is gone."""
        rid = res.trr.resource_id
        record = self._records.pop(rid, None)
        if record is None:
            raise TemotoError(ErrorCode.RESOURCE_FAILED, Subsystem.ER_MANAGER,
                              'the journal has no record of the processes of resource %d' % rid)
        specs, procs = [], []
        for p in record['processes']:
            spec = ProcessSpec(argv=p['argv'], env={}, log_path=p['log_path'], label=p['label'],
                               node_names=p['node_names'])
            specs.append(spec)
            proc = self.supervisor.adopt(spec, p['pid'], p['start'], p['started'])
            if proc is None:
                self._stop_all(procs)
                if spec.node_names:
                    threading.Thread(target=self._cleanup_master, args=(list(spec.node_names),),
                                     name='er-master-cleanup', daemon=True).start()
                raise TemotoError(ErrorCode.PROCESS_STOPPED, Subsystem.ER_MANAGER,
                                  '%s: process %d (%s) exited while the ER Manager was down; last output:\n%s'
                                  % (record['label'], p['pid'], spec.command,
                                     _tail(p['log_path'], self.config.log_tail_lines)))
            procs.append(proc)
        resource = Resource(rid, Plan(record['label'], record['log_path'], specs, record['command']))
        for proc in procs:
            proc.resource = resource
        resource.procs, resource.ready = procs, True
        with self._lock:
            self._resources[rid] = resource
        rospy.loginfo('%s: adopted %s (pid %s) after a restart', NAME, resource.label,
                      ', '.join(str(p.pid) for p in procs))
        self._speak_for_nodes(procs)

    def _speak_for_nodes(self, procs: list) -> None:
        """Have this node's master check register the ROS nodes of ``procs`` again with a master that
        restarted (the robot host rebooted, and this manager is on the station): a node registers only when it
        starts, and a roscpp program (a throttle of a robot's topic) never again, so its subscriptions would go
        quiet with no error anywhere. Done in the background: the master is asked what each node offers."""
        rejoin = master_rejoin.ensure_started()
        if rejoin is not None and procs:
            threading.Thread(target=self._find_nodes, args=(rejoin, list(procs)), name='er-speak-for-nodes',
                             daemon=True).start()

    def _find_nodes(self, rejoin: master_rejoin.MasterRejoin, procs: list) -> None:
        """Each process's nodes, found by the ports it listens on (a program's node may be anonymous: a
        throttle's is). A plain executable may register its node after it counted as started, so it is looked
        for until its registration bound; one that registers none is not a ROS node."""
        for proc in procs:
            deadline = time.monotonic() + self.config.registration_timeout
            delay = self.config.ready_poll_interval
            nodes, found = [], set()          # what is known if the master does not answer at all
            while True:
                try:
                    nodes = master_rejoin.nodes_of_processes([proc.pid, *_descendants(proc.pid)])
                except master_rejoin.XMLRPC_ERRORS as err:
                    rospy.logwarn('%s: could not learn the nodes of pid %d (%s): a restarted master will not get '
                                  'them back until they start again', NAME, proc.pid, err)
                    break
                found = {node.name for node in nodes}
                if not proc.alive or time.monotonic() >= deadline or (nodes and set(proc.spec.node_names) <= found):
                    break
                time.sleep(delay)             # the process is still registering: looked at again, less often
                delay = min(2 * delay, 1.0)
            proc.nodes = sorted(found)
            for node in nodes:
                rejoin.adopt(node)
            if not proc.alive:                # exited meanwhile, perhaps after _on_exit disowned its nodes
                for node in nodes:
                    rejoin.disown(node.name)

    def _untold_children(self, known: set) -> list:
        """[(pid, start)] of the previous incarnations' children that their leash does not know: processes
        with this manager's owner in their environment whose parent does not have it (the root of what a
        manager started; a node's own children are stopped with its group), other than this
        incarnation's own (its zygote may be starting this moment)."""
        ours = {child.pid for child in psutil.Process().children(recursive=True)}
        marked = {pid for pid, _ in processes_with_env(OWNER_ENV, self.resolver.env[OWNER_ENV], exclude=list(ours))}
        out = []
        for pid in sorted(marked - known):
            try:
                parent = psutil.Process(pid).ppid()
            except psutil.Error:
                continue              # gone already
            start = start_ticks(pid)
            if parent not in marked and parent not in ours and start is not None:
                out.append((pid, start))
        return out

    def _stop_unclaimed(self, leashed: list) -> None:
        """Children the leash kept that no recovered resource claimed (they were starting, or their
        resource was released, when the manager died), and children the previous incarnation started but
        died before telling its leash about (known by the owner in their environment): stopped, so that
        nothing runs unowned."""
        with self._lock:
            claimed = {p.pid for r in self._resources.values() for p in r.procs}
        if OWNER_ENV in self.resolver.env:
            leashed = leashed + self._untold_children({pid for pid, _ in leashed})
        strays = []
        for pid, start in leashed:
            if pid in claimed:
                continue
            proc = self.supervisor.adopt(ProcessSpec(argv=['pid %d' % pid], env={}, log_path=os.devnull,
                                                     label='unclaimed child'), pid, start, time.time())
            if proc is not None:
                strays.append(proc)
        if strays:
            rospy.logwarn('%s: stopping %d child(ren) of the previous incarnation that no resource claims: pid %s',
                          NAME, len(strays), ', '.join(str(p.pid) for p in strays))
            for proc in strays:
                proc.stopping = True
            self._stop_all(strays)
        for rid in self._records:
            self.rr.drop_owner_state(PROCESS_KEY % rid)
        self._records.clear()

    # -- failures ----------------------------------------------------------------------------------

    def _on_exit(self, proc: ManagedProcess, info: ExitInfo) -> None:
        rejoin = master_rejoin.ensure_started()
        for name in proc.nodes if rejoin is not None else ():
            rejoin.disown(name)               # registering it again would bring a dead node back to the master
        if proc.spec.node_names:
            # a node that died without unregistering would stay in `rosnode list` with its topics
            threading.Thread(target=self._cleanup_master, args=(list(proc.spec.node_names),),
                             name='er-master-cleanup', daemon=True).start()
        resource: Optional[Resource] = getattr(proc, 'resource', None)
        if resource is None or self._closing:
            return
        with resource.lock:
            if not resource.ready or resource.stopping or resource.failed_by is not None:
                return                        # loading: _load reports it; unloading: intentional; or reported
            resource.failed_by = proc
            others = [p for p in resource.procs if p is not proc]
        message = '%s%s' % (self._which(resource, proc.pid) or resource.label + ': ', info.message())
        if others:
            message += '\n(stopping the other node(s) of %s: %s)' % (resource.label,
                                                                    ', '.join(resource.node_of(p) for p in others))
        rospy.logerr('%s: %s', NAME, message)
        err = TemotoError(ErrorCode.PROCESS_STOPPED, Subsystem.ER_MANAGER, message)
        try:
            self.rr.send_status(resource.resource_id, ResourceStatus.FAILED, message, error_stack=err.stack)
        except Exception as e:                # e.g. the resource was unloaded meanwhile
            rospy.logwarn('%s: could not report the exit of pid %d: %s', NAME, proc.pid, e)
        if others:                            # after the report: stopping takes up to the grace periods
            threading.Thread(target=self._stop_all, args=(others,), name='er-stop-rest', daemon=True).start()

    def _cleanup_master(self, node_names: list) -> None:
        for name in node_names:
            try:
                gone = master.cleanup_dead_node(self.master_uri, name)
            except Exception as e:          # the master being away must not take the manager down
                rospy.logwarn('%s: cleaning up %s at the master: %s', NAME, name, e)
                continue
            if gone:
                rospy.loginfo('%s: %s died without unregistering; removed its %d registration(s) from the master',
                              NAME, name, gone)

    # -- introspection and shutdown ------------------------------------------------------------------

    def processes_json(self) -> str:
        """One row per resource (loading or loaded), each with its processes."""
        with self._lock:
            resources = list(self._resources.values()) + list(self._stopping.values())
        rows = [r.snapshot() for r in resources]
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
        if self.leash is not None:
            self.leash.release()
        self._processes_srv.shutdown()


def _record_of(resource: Resource) -> dict:
    """What a restarted manager needs to adopt the resource's processes (kept in the journal)."""
    return {'label': resource.label, 'command': resource.plan.command, 'log_path': resource.plan.log_path,
            'processes': [{'pid': p.pid, 'start': start_ticks(p.pid), 'started': p.started, 'argv': p.spec.argv,
                           'label': p.spec.label, 'node_names': p.spec.node_names, 'log_path': p.spec.log_path}
                          for p in resource.procs]}


def _descendants(pid: int) -> List[int]:
    """A process's children, theirs, and so on (a node under a launch-prefix wrapper)."""
    try:
        return [child.pid for child in psutil.Process(pid).children(recursive=True)]
    except psutil.Error:
        return []


def _tail(path: str, lines: int) -> str:
    return read_tail(path, lines)
