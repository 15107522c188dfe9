"""ActionBase: what an action plugin derives from.

Life of an instance (one node of a running graph), driven by the graph runner:

1. ``on_start()``  set up; request resources. For an *asynchronous* action this is also where
   it sets the outputs its children need: once ``on_start`` returns, the children start (as in
   the original TTP engine, where an asynchronous task's start returned and the object lived on).
2. ``execute()``   a *synchronous* action does its work here and returns; its outputs then flow
   to the children. An *asynchronous* action runs its loop here, ``while self.action_ok(): ...``,
   until it is stopped (the default loop just waits for the stop).
3. ``on_stop()``   always runs after ``on_start`` was entered, whatever happened.
   An action that cannot go on (its resources are lost for good) calls ``fail(reason)`` from any
   thread: its loop is stopped, and it ends FAILED with that reason, and its graph with it.
   A resource requested without a failure policy of its own (``on_status=``) is reloaded by its
   interface on FAILED; if that reload gives up, the action fails the same way.
4. Then everything the instance requested is released: its manager interfaces are shut down
   and its own Resource Registrar (``action_<name>_<uid>``) unloads whatever it still holds.

Manager interfaces (sensor, output, context, ER, robot) are imported lazily, so an engine runs and
indexes even when one of those packages is missing; using a missing one raises ActionError.
"""
from __future__ import annotations

import collections
import importlib
import json
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import rospy

from temoto_core.rr.messages import legal_name

from .umrf import ActionDescriptor

# attribute -> (module, class): the interfaces each action can use, written by the managers' owners.
MANAGER_INTERFACES = {
    'sensor_manager': ('temoto_sensor_manager.interface', 'SensorManagerInterface'),
    'output_manager': ('temoto_output_manager.interface', 'OutputManagerInterface'),
    'context_manager': ('temoto_context_manager.interface', 'ContextManagerInterface'),
    'er_manager': ('temoto_er_manager.interface', 'ERManagerInterface'),
    'robot_manager': ('temoto_robot_manager.interface', 'RobotManagerInterface'),
    # the Sensor Manager of the operator's station (the engine's own namespace): sensors that are not on a
    # robot, such as a fixed scanner in the lab, which stay in reach when a robot's link fails
    'station_sensor_manager': ('temoto_sensor_manager.interface', 'SensorManagerInterface'),
}
# the managers that run on a robot (robot.launch): an action's ``robot`` input names their namespace
ROBOT_MANAGERS = ('sensor_manager', 'er_manager', 'robot_manager')


class ActionError(RuntimeError):
    """An action cannot do what it was asked; the message is shown to the operator."""


@dataclass
class ActionContext:
    """Everything the engine hands to one action instance."""
    descriptor: ActionDescriptor
    instance_id: int
    graph_name: str
    inputs: dict
    uid: str                                        # unique in the engine process
    config: dict = field(default_factory=dict)      # engine param ~actions/<name>
    namespace: str = 'temoto'
    rr_factory: Callable[[str], Any] | None = None  # registrar name -> ResourceRegistrar
    publish_event: Callable[[dict], None] = lambda ev: None
    publish_feedback: Callable[[str], None] = lambda text: None
    engine: Any = None                              # facade for actions that manage others (stop)
    # attr -> factory(rr): replaces the import of MANAGER_INTERFACES[attr] (tests, other deployments)
    interface_factories: dict = field(default_factory=dict)


def default_rr_factory(namespace: str) -> Callable[[str], Any]:
    def make(name: str):
        from temoto_core.errors import Subsystem          # lazy: tests without ROS pass their own factory
        from temoto_core.rr import ResourceRegistrar
        return ResourceRegistrar(name, namespace=namespace, subsystem=Subsystem.ACTION_ENGINE)
    return make


class ActionBase:
    """Base class of every action plugin. Override on_start / execute / on_stop."""

    def __init__(self, context: ActionContext):
        self.context = context
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._mailbox: collections.deque = collections.deque()
        self._outputs: dict = {}
        self._rr = None
        self._interfaces: dict = {}
        self._res_lock = threading.RLock()
        self._failure: str | None = None

    # ------------------------------------------------------------------ hooks
    def on_start(self) -> None:
        """Set up. Asynchronous actions set the outputs their children need here."""

    def execute(self) -> None:
        """Synchronous: do the work. Asynchronous: run until stopped (default: just wait)."""
        while self.action_ok():
            self.wait(3600.0)

    def on_stop(self) -> None:
        """Tidy up; resources are released by the engine right after this."""

    # ------------------------------------------------------------------ identity
    @property
    def name(self) -> str:
        return self.context.descriptor.name

    @property
    def instance_id(self) -> int:
        return self.context.instance_id

    @property
    def config(self) -> dict:
        return self.context.config

    @property
    def engine(self):
        return self.context.engine

    @property
    def rr_name(self) -> str:
        return 'action_%s_%s' % (self.name, self.context.uid)

    # ------------------------------------------------------------------ parameters
    @property
    def inputs(self) -> dict:
        return dict(self.context.inputs)

    def input(self, name: str, default: Any = None) -> Any:
        if name not in self.context.descriptor.inputs:
            raise ActionError('%s has no input parameter %r' % (self.name, name))
        return self.context.inputs.get(name, default)

    def set_output(self, name: str, value: Any) -> None:
        """Set a declared output parameter; the type is checked against the descriptor."""
        spec = self.context.descriptor.outputs.get(name)
        if spec is None:
            raise ActionError('%s has no output parameter %r (outputs: %s)'
                              % (self.name, name, sorted(self.context.descriptor.outputs)))
        err = spec.check(value)
        if err:
            raise ActionError('%s: %s' % (self.name, err))
        self._outputs[name] = value

    @property
    def outputs(self) -> dict:
        return dict(self._outputs)

    # ------------------------------------------------------------------ run control
    def action_ok(self) -> bool:
        """False once a stop was requested; a run loop must then return promptly."""
        return not self._stop.is_set() and not rospy.is_shutdown()

    def fail(self, reason: str) -> None:
        """End this action FAILED with ``reason`` (callable from any thread, e.g. a status callback).

        The first reason is kept. The run loop sees ``action_ok()`` turn False, ``on_stop`` runs,
        resources are released, and the graph reports FAILED with the reason.
        """
        with self._cond:
            first = self._failure is None
            if first:
                self._failure = reason
        self.log_err('failing: %s' % reason)
        if first:
            # said now: the node's FAILED state comes only once what it holds is released, which for a robot's
            # feature means stopping its processes (seconds); the operator must not wait for that to hear it
            self.event('failing', reason=reason)
            self.feedback('failing: %s' % reason)
        self.request_stop()

    @property
    def failure(self) -> str | None:
        """Why this action failed (``fail``), or None."""
        with self._cond:
            return self._failure

    def request_stop(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    def wait(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s, waking early on stop (or a post); returns action_ok()."""
        with self._cond:
            if self.action_ok():
                self._cond.wait(max(0.0, timeout))
        return self.action_ok()

    def post(self, item: Any) -> None:
        """Hand an item (e.g. a resource status event from a callback thread) to the run loop."""
        with self._cond:
            self._mailbox.append(item)
            self._cond.notify_all()

    def next_item(self, timeout: float) -> Any:
        """The next posted item, or None after ``timeout`` s or when stopping."""
        deadline = time.monotonic() + max(0.0, timeout)
        with self._cond:
            while not self._mailbox and self.action_ok():
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            return self._mailbox.popleft() if self._mailbox else None

    # ------------------------------------------------------------------ resources
    @property
    def rr(self):
        """This instance's own Resource Registrar, created on first use."""
        with self._res_lock:
            if self._rr is None:
                factory = self.context.rr_factory or default_rr_factory(self.context.namespace)
                self._rr = factory(self.rr_name)
            return self._rr

    def interface(self, attr: str):
        """The manager interface called ``attr`` (see MANAGER_INTERFACES), bound to this action's RR."""
        with self._res_lock:
            if attr in self._interfaces:
                return self._interfaces[attr]
            cls = self.context.interface_factories.get(attr)
            if cls is None:
                module_name, cls_name = MANAGER_INTERFACES[attr]
                try:
                    cls = getattr(importlib.import_module(module_name), cls_name)
                except (ImportError, AttributeError) as e:
                    raise ActionError('%s needs %s.%s, which is not available: %s'
                                      % (self.name, module_name, cls_name, e)) from None
            namespace = self.manager_namespace(attr)
            itf = cls(self.rr, namespace=namespace) if namespace else cls(self.rr)
            if hasattr(itf, 'on_lost'):
                # a resource that its interface's default policy could not replace fails the action
                itf.on_lost = lambda resource_id, err, attr=attr: self.fail(
                    'lost a %s resource (%d) for good: %s' % (attr.replace('_', ' '), resource_id, err))
            self._interfaces[attr] = itf
            return itf

    def manager_namespace(self, attr: str) -> str | None:
        """The TeMoto namespace the manager ``attr`` runs in, if not the engine's own.

        A robot's managers run on the robot, under the robot's namespace, while the
        engine runs on the operator's station (docs/two_hosts.md): the action's
        config says where, as ``manager_namespaces: {sensor_manager: vaultbot}``.
        An action that takes a ``robot`` input ("show the environment of vaultbot_2")
        asks that robot's own managers (ROBOT_MANAGERS) instead, so that one station
        serves several robots.
        """
        robot = self.context.inputs.get('robot') if 'robot' in self.context.descriptor.inputs else None
        if attr in ROBOT_MANAGERS and robot not in (None, ''):
            if not isinstance(robot, str) or not legal_name(robot.strip('/'), base=True):
                raise ActionError('%s: robot %r is not a TeMoto namespace' % (self.name, robot))
            return robot.strip('/')
        where = self.config.get('manager_namespaces') or {}
        if not isinstance(where, dict):
            raise ActionError('%s: manager_namespaces must map a manager to a TeMoto namespace, got %r'
                              % (self.name, where))
        namespace = where.get(attr)
        if namespace is None or namespace == '':
            return None
        if not isinstance(namespace, str) or not legal_name(namespace.strip('/'), base=True):
            raise ActionError('%s: manager_namespaces.%s is %r, not a TeMoto namespace' % (self.name, attr, namespace))
        return namespace.strip('/')

    @property
    def sensor_manager(self):
        return self.interface('sensor_manager')

    @property
    def station_sensor_manager(self):
        return self.interface('station_sensor_manager')

    @property
    def output_manager(self):
        return self.interface('output_manager')

    @property
    def context_manager(self):
        return self.interface('context_manager')

    @property
    def er_manager(self):
        return self.interface('er_manager')

    @property
    def robot_manager(self):
        return self.interface('robot_manager')

    def release_resources(self) -> list[str]:
        """Shut the interfaces down and the registrar (which unloads everything it holds).

        Returns the problems met, each already logged; releasing never raises.
        """
        problems = []
        with self._res_lock:
            interfaces, self._interfaces = self._interfaces, {}
            rr, self._rr = self._rr, None
        for attr, itf in interfaces.items():
            shutdown = getattr(itf, 'shutdown', None)
            if shutdown:
                try:
                    shutdown()
                except Exception as e:      # keep releasing the rest
                    problems.append('%s interface shutdown: %s' % (attr, e))
        if rr is not None:
            try:
                rr.shutdown()
            except Exception as e:
                problems.append('registrar %s shutdown: %s' % (self.rr_name, e))
        for p in problems:
            self.log_warn(p)
        return problems

    # ------------------------------------------------------------------ reporting
    def _prefix(self, msg: str) -> str:
        return '[%s/%s_%d] %s' % (self.context.graph_name, self.name, self.instance_id, msg)

    def log_info(self, msg: str) -> None:
        rospy.loginfo(self._prefix(msg))

    def log_warn(self, msg: str) -> None:
        rospy.logwarn(self._prefix(msg))

    def log_err(self, msg: str) -> None:
        rospy.logerr(self._prefix(msg))

    def feedback(self, text: str) -> None:
        """A short sentence for the operator on /<ns>/action_engine/feedback."""
        self.context.publish_feedback('%s: %s' % (self.name, text))

    def event(self, kind: str, **fields) -> None:
        """A state change of this action, logged and published on /<ns>/action_engine/events."""
        ev = {'event': kind, 'graph': self.context.graph_name, 'action': self.name,
              'instance_id': self.instance_id}
        ev.update(fields)
        self.log_info('%s %s' % (kind, json.dumps(fields, sort_keys=True, default=str)))
        self.context.publish_event(ev)
