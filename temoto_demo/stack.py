"""The nodes of ``launch/demo.launch``, each in its own process group, stopped in reverse order.

``roslaunch`` would start the same nodes, but as one process group with one shutdown sequence. The
demo needs more: the action engine must stop first (its registrars unload the displays and sensors
while the managers still run), each component must have its own group so a stuck one is killed
without touching the rest, and the parameters can be overridden (the sensor priority). So the launch
file is *read* with roslaunch's own loader (arguments, includes, ``rosparam`` files and remaps all
resolved as roslaunch would) and its nodes are started here directly.

Nodes with ``respawn="true"`` (``recovery:=true``) are started again when they die, as roslaunch
does: one thread waits on a pidfd per such node, so a death is seen at once.
"""
from __future__ import annotations

import os
import select
import shlex
import signal
import sys
import threading
import time
import xmlrpc.client
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence

from temoto_core.processes import LoggedChild, stop_process_group
from temoto_core.wait import wait_for

# Seconds of SIGINT grace per node: the engine stops its graphs (stop_timeout_s 15 s at worst) and
# the managers unload what they hold; everything else exits at once.
SIGINT_GRACE = {'temoto_action_engine': 20.0, 'temoto_sensor_manager': 10.0, 'temoto_output_manager': 10.0,
                'temoto_er_manager': 10.0, 'temoto_context_manager': 10.0}
DEFAULT_GRACE = 5.0


@dataclass
class NodeSpec:
    package: str
    executable: str
    name: str           # fully qualified, e.g. /temoto_er_manager
    argv: List[str]
    env: Dict[str, str]
    respawn: bool = False
    respawn_delay: float = 0.0


def load_launch(path: str, args: Sequence[str] = ()) -> tuple:
    """(node specs in launch order, {param: value}) of a launch file, as roslaunch resolves it."""
    import roslaunch.config     # lazy: roslaunch's loader takes ~0.2 s to import
    config = roslaunch.config.load_config_default([(path, list(args))], None)
    params = {k: p.value for k, p in config.params.items() if k not in ('/rosdistro', '/rosversion')}
    return config, params


def _argv_for(path: str) -> List[str]:
    with open(path, 'rb') as f:
        first = f.readline()
    return [sys.executable, path] if b'python' in first else [path]


def node_specs(config, env: Dict[str, str]) -> List[NodeSpec]:
    import roslib.packages
    import rospkg
    rospack = rospkg.RosPack(rospkg.get_ros_paths(env))
    specs = []
    for n in config.nodes:
        found = roslib.packages.find_node(n.package, n.type, rospack)
        if not found:
            raise FileNotFoundError('%s: no executable %r in package %r' % (n.filename, n.type, n.package))
        ns = (n.namespace or '/').rstrip('/')
        full = '%s/%s' % (ns, n.name)
        argv = _argv_for(found[0]) + shlex.split(n.args or '') + ['%s:=%s' % tuple(r) for r in n.remap_args]
        argv += ['__name:=' + n.name] + (['__ns:=' + ns] if ns else [])
        node_env = dict(env)
        node_env.update(dict(n.env_args))
        specs.append(NodeSpec(n.package, n.type, full, argv, node_env, bool(n.respawn),
                              float(n.respawn_delay or 0.0)))
    return specs


class Stack:
    """Start with :meth:`start`, stop with :meth:`stop` (reverse order, by process group)."""

    def __init__(self, launch_path: str, env: Dict[str, str], log_dir: str, launch_args: Sequence[str] = (),
                 param_overrides: Optional[Dict[str, object]] = None,
                 wrap: Optional[Callable[[List[str]], List[str]]] = None) -> None:
        """``wrap``: how a node's command line is run elsewhere (on another host: ``TwoHosts.argv``)."""
        self.launch_path = launch_path
        self.wrap = wrap or (lambda argv: list(argv))
        self.env = env
        self.log_dir = log_dir
        self.launch_args = list(launch_args)
        self.param_overrides = dict(param_overrides or {})
        self.running: List[tuple] = []      # (NodeSpec, LoggedChild)
        self.params: Dict[str, object] = {}
        self.respawns: List[dict] = []      # {'name', 'died', 'started', 'pid'} (time.monotonic())
        self._lock = threading.Lock()
        self._wake_r, self._wake_w = os.pipe2(os.O_CLOEXEC | os.O_NONBLOCK)
        self._stopping = False
        self._respawner: Optional[threading.Thread] = None

    @property
    def pids(self) -> List[int]:
        return [p.pid for _, p in self.running]

    def start(self, timeout: float = 40.0) -> None:
        """Upload the parameters, start every node at once, return when all are registered."""
        config, self.params = load_launch(self.launch_path, self.launch_args)
        unknown = [k for k in self.param_overrides if k not in self.params]
        if unknown:
            raise KeyError('%s sets no parameter %s' % (os.path.basename(self.launch_path), ', '.join(unknown)))
        self.params.update(self.param_overrides)
        master = xmlrpc.client.ServerProxy(self.env['ROS_MASTER_URI'])
        self._upload_params(master)
        os.makedirs(self.log_dir, exist_ok=True)
        for spec in node_specs(config, self.env):
            self.running.append((spec, LoggedChild(self.wrap(spec.argv), spec.env, self._log_of(spec), spec.name)))

        def all_registered():
            for spec, proc in self.running:
                if not proc.alive():
                    raise RuntimeError('%s exited (rc %s) during startup; log %s:\n%s'
                                       % (spec.name, proc.returncode, proc.log_path, proc.log()))
            return all(master.lookupNode('/temoto_demo', spec.name)[0] == 1 for spec, _ in self.running)

        wait_for(all_registered, timeout, 'the nodes of demo.launch to register')
        if any(spec.respawn for spec, _ in self.running):
            self._respawner = threading.Thread(target=self._respawn_loop, name='demo-respawn', daemon=True)
            self._respawner.start()

    def _upload_params(self, master) -> None:
        for key, value in self.params.items():
            code, msg, _ = master.setParam('/temoto_demo', key, value)
            if code != 1:
                raise RuntimeError('could not set %s: %s' % (key, msg))

    def node(self, name: str) -> LoggedChild:
        """The process running node ``name`` now (a respawn replaces it)."""
        with self._lock:
            return next(proc for spec, proc in self.running if spec.name == name)

    def _respawn_loop(self) -> None:
        while True:
            with self._lock:
                if self._stopping:
                    return
                watched = {}
                for i, (spec, proc) in enumerate(self.running):
                    if spec.respawn:
                        try:
                            watched[os.pidfd_open(proc.pid)] = i
                        except OSError:         # gone between the listing and the open: the next round sees it
                            pass
            try:
                readable, _, _ = select.select([self._wake_r] + list(watched), [], [])
            finally:
                for fd in watched:
                    os.close(fd)
            for fd in readable:
                if fd != self._wake_r and fd in watched:
                    self._respawn(watched[fd])

    def _respawn(self, index: int) -> None:
        died = time.monotonic()
        with self._lock:
            if self._stopping:
                return
            spec, old = self.running[index]
        old.proc.wait()
        if spec.respawn_delay:
            time.sleep(spec.respawn_delay)
        # the master may have started again since the parameters were uploaded (a robot host that lost
        # power), and a new master has none: a node respawned without them would come up with its defaults
        # (another namespace, no journal), a different node under the same name
        try:
            self._upload_params(xmlrpc.client.ServerProxy(self.env['ROS_MASTER_URI']))
        except (OSError, RuntimeError) as e:
            sys.stderr.write('%s: respawned without uploading the parameters again: %s\n' % (spec.name, e))
        with self._lock:
            if self._stopping:
                return
            proc = LoggedChild(self.wrap(spec.argv), spec.env, self._log_of(spec), spec.name)
            self.running[index] = (spec, proc)
            self.respawns.append({'name': spec.name, 'died': died, 'started': time.monotonic(), 'pid': proc.pid,
                                  'returncode': old.proc.returncode})

    def _log_of(self, spec: NodeSpec) -> str:
        return os.path.join(self.log_dir, spec.name.strip('/').replace('/', '.') + '.log')

    def dead(self) -> List[str]:
        return ['%s (rc %s)' % (s.name, p.returncode) for s, p in self.running if not p.alive()]

    def kill(self) -> None:
        """A power loss: every node's process group SIGKILLed at once and reaped, nothing respawned, no grace.
        Processes in other groups (what the ER Manager started) are the caller's; a new Stack boots again."""
        self._halt_respawns()
        for _, proc in self.running:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        for _, proc in self.running:
            proc.proc.wait(10.0)
        self.running.clear()

    def _halt_respawns(self) -> None:
        with self._lock:
            self._stopping = True
        os.write(self._wake_w, b'x')
        if self._respawner is not None:
            self._respawner.join(10.0)

    def stop(self, on_step=None) -> List[tuple]:
        """The action engine first (its actions release what they hold through the managers), then the
        managers and the simulation together: each stops its own children, and rospy's shutdown takes
        most of a second per node, which in series added up to ~10 s. Returns (name, rc)."""
        self._halt_respawns()
        results = []
        lock = threading.Lock()

        def stop_one(spec, proc):
            grace = SIGINT_GRACE.get(spec.name.strip('/'), DEFAULT_GRACE)
            rc = stop_process_group(proc.proc, sigint_grace=grace, sigterm_grace=3.0)
            with lock:
                results.append((spec.name, rc))
                if on_step:
                    on_step(spec.name, rc)

        if self.running:
            stop_one(*self.running.pop())           # the last launched: the action engine
        threads = [threading.Thread(target=stop_one, args=item) for item in reversed(self.running)]
        self.running.clear()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return results
