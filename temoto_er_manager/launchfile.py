"""A ``.launch`` file turned into parameters plus one :class:`ProcessSpec` per node; no roslaunch at run time.

Why not run ``roslaunch``: its process monitor polls every 0.1 s, a wrapper
around it must shut the rest of the launch down before its own exit tells the
supervisor anything (a node death reached consumers after ~0.6 s), and starting
a ``ROSLaunchParent`` costs ~2 s before the first node even runs. So the ER
Manager uses only roslaunch's *loader* (as ``roslaunch.config.load_config_default`` does:
args, includes, groups and namespaces, remaps, params, ``$(find)``, ``$(arg)``,
``$(anon)``, ``<env>``) and starts each node itself, as its own supervised child.
Every node's exit is then seen at once by the supervisor's pidfd reaper.

The roslaunch rules kept, and the deliberate differences:

- namespace: the request's ``ros_namespace`` is the launch's root namespace
  (as ``ROS_NAMESPACE`` is for ``roslaunch``); ``<group ns="/abs">`` stays absolute;
- parameters: ``clear_params`` namespaces are deleted, then every ``<param>`` and
  ``<rosparam>`` is set, before any node starts (``roslaunch`` does the same, and,
  like it, nothing is deleted on unload);
- a node: executable found with the rosrun rules (unique, executable, below its
  package), argv = executable + ``args`` (shlex) + ``from:=to`` remaps +
  ``__name:=`` + ``__ns:=``; env = the manager's + ``ROS_NAMESPACE`` + the node's
  ``<env>``; cwd = ``ROS_HOME`` or, with ``cwd="node"``, the executable's directory;
- every node is *required*: any node's death fails the whole resource (reported
  FAILED, the other nodes are stopped). ``respawn="true"`` is not honoured (a
  warning is logged): TeMoto's recovery is the consumer's reload after FAILED, and
  a silent local respawn would hide the failure from it;
- ``launch-prefix`` is split with shlex and run without a shell; since it runs a
  command of its own it follows the ``sys_execute`` rule: its first word must be
  in the manager's ``sys_allowlist``, else the load is refused;
- refused: nodes on a remote ``<machine>``, a node package outside the
  ``package_allowlist``, two nodes with the same name. ``<test>`` tags are ignored
  (as ``roslaunch`` does). ``output=`` is ignored: all output goes to the resource's log.
- ``<param command="...">`` runs at load time inside the manager, as it would
  inside ``roslaunch``: a launch file is trusted as much as its package's executables.
"""
from __future__ import annotations

import os
import shlex
import sys
import threading
from dataclasses import dataclass, field
from typing import Any, Callable

import roslaunch.config
import roslaunch.core
import roslaunch.loader
import roslaunch.xmlloader
import rospkg

from .policy import RequestRefused, check_package_allowed
from .supervisor import ProcessSpec

# roslaunch is imported here, not at the first launch file: a manager under a warm-respawn parent then has it
# before it is forked, and the first launch file after a restart no longer imports 529 modules (0.23 s) in a
# load's thread. (The ER Manager wedges of the chaos history, seed 17, which first pointed here, came from a
# fork with a preexec_fn: process_group.popen_dying_with_this_thread says why.)

# roslaunch's loader keeps module-level caches (rospack, anonymous names): one load at a time
_load_lock = threading.Lock()


@dataclass
class LaunchPlan:
    """What loading one launch file means: parameters to set, then nodes to start."""
    path: str
    params: dict[str, Any] = field(default_factory=dict)       # absolute name -> value
    clear_params: list[str] = field(default_factory=list)
    nodes: list[ProcessSpec] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def load_launch_config(path: str, args: list[str], ns: str):
    """roslaunch's own model of ``path`` with ``args`` (``name:=value``) under root namespace ``ns``.

    This is ``roslaunch.config.load_config_default`` minus its ``load_roscore``
    step: that step parses roscore.xml, whose ``/rosversion`` and ``/rosdistro``
    params run two commands (~0.2 s per load) to set what the running roscore
    already set, and declares core nodes that are never started here.
    """
    with _load_lock:
        try:
            config = roslaunch.config.ROSLaunchConfig()
            loader = roslaunch.xmlloader.XmlLoader()
            # __ns:= in the loader's argv sets the root namespace, exactly like ROS_NAMESPACE for roslaunch
            loader.load(path, config, argv=list(args) + ['__ns:=' + ns], verbose=False)
            config.assign_machines()
            return config
        except Exception as e:           # RLException, XML errors, $(find) of a missing package, bad $(arg)
            raise RequestRefused('BAD_REQUEST', 'launch file %s cannot be loaded: %s' % (path, e)) from None


def plan_launch(path: str, args: list[str], ns: str, *, env: dict, log_path: str, label: str,
                find_executable: Callable[[str, str], str], package_allowlist: list[str],
                sys_allowlist: list[str], interpreter_argv: Callable[[str], list[str]]) -> LaunchPlan:
    """Load ``path`` and build the plan; raises :class:`RequestRefused` (and changes nothing) when refused."""
    config = load_launch_config(path, args, ns)
    plan = LaunchPlan(path=path, clear_params=list(config.clear_params),
                      params={key: p.value for key, p in config.params.items()},
                      warnings=list(getattr(config, 'config_errors', [])))
    if config.executables:
        raise RequestRefused('BAD_REQUEST', 'launch file %s: <executable> entries are not supported' % path)
    seen = set()
    for node in config.nodes:
        full = (node.namespace.rstrip('/') + '/' + node.name) if node.name else ''
        where = 'launch file %s, node %s (%s/%s)' % (os.path.basename(path), full or '?', node.package, node.type)
        if not node.name:
            raise RequestRefused('BAD_REQUEST', '%s: a node needs a name' % where)
        if full in seen:
            raise RequestRefused('BAD_REQUEST', '%s: the node name appears twice' % where)
        seen.add(full)
        check_package_allowed(node.package, package_allowlist, what='%s: package' % where)
        if node.machine is not None and not roslaunch.core.is_machine_local(node.machine):
            raise RequestRefused('NOT_ALLOWED', '%s: runs on remote machine %r; only local nodes are supported'
                                 % (where, node.machine.address))
        exe = find_executable(node.package, node.type)
        argv = interpreter_argv(exe)
        # a launch-prefix (gdb, valgrind, ...) must see a real process start
        preloadable = not node.launch_prefix and len(argv) == 2 and argv[0] == sys.executable
        if node.launch_prefix:
            try:
                prefix = shlex.split(node.launch_prefix)
            except ValueError as e:
                raise RequestRefused('BAD_REQUEST', '%s: launch-prefix cannot be split: %s' % (where, e)) from None
            if prefix and prefix[0] not in sys_allowlist:
                raise RequestRefused('NOT_ALLOWED', '%s: launch-prefix %r runs %r, which is not in this manager\'s '
                                     'sys_allowlist (%s)' % (where, node.launch_prefix, prefix[0],
                                                             ', '.join(sys_allowlist) or 'empty'))
            argv = prefix + argv
        try:
            node_args = shlex.split(node.args or '')
        except ValueError as e:
            raise RequestRefused('BAD_REQUEST', '%s: args cannot be split: %s' % (where, e)) from None
        node_ns = node.namespace.rstrip('/') or '/'
        argv += node_args + ['%s:=%s' % (src, dst) for src, dst in node.remap_args]
        argv += ['__name:=' + node.name, '__ns:=' + node_ns]
        node_env = dict(env)
        node_env.pop('ROS_NAMESPACE', None)
        if node_ns != '/':
            node_env['ROS_NAMESPACE'] = node_ns
        node_env.update((str(k), str(v)) for k, v in node.env_args)
        if node.cwd == 'node':
            cwd = os.path.dirname(exe)
        else:
            cwd = rospkg.get_ros_home(env=node_env)
            os.makedirs(cwd, exist_ok=True)
        if node.respawn:
            plan.warnings.append('%s: respawn="true" is not honoured; a death is reported FAILED instead' % where)
        plan.nodes.append(ProcessSpec(argv=argv, env=node_env, log_path=log_path, cwd=cwd,
                                      label='%s %s' % (label, full), node_names=[full], preloadable=preloadable))
    if not plan.nodes:
        raise RequestRefused('BAD_REQUEST', 'launch file %s starts no node' % path)
    return plan
