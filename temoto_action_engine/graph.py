"""Running a UMRF graph: one thread per action node, started when its parents allow it.

Semantics (UMRF, as in the original engine):
- a node starts once every *required* parent has released it and every required input is
  present (given in the graph, a descriptor default, or an output of a parent);
- a parent *releases* its children when its outputs are ready: a synchronous action when
  ``execute()`` returns, an asynchronous one when ``on_start()`` returns (it keeps running);
- a parent's outputs fill the children's inputs of the same name that the graph left empty;
- siblings run in parallel; a node or the whole graph can be stopped;
- a node that can no longer start (a required parent failed or stopped before releasing it,
  or an input never arrived) is CANCELLED with the reason, and so are its descendants;
- a node that fails (it raised, or it lost its resources for good and called ``fail``) ends
  FAILED with the reason, and the graph fails with it: the nodes running at that moment are
  stopped (what they do was asked together with what failed), the children that require the
  failed node are cancelled, and only nodes that declared it an optional parent go on. So a
  graph is never shown RUNNING with part of it dead and the rest carrying on as if it were not;
- the graph is finished when every node is FINISHED, FAILED or CANCELLED; it is FAILED, with
  the first failure as its reason, when any node failed.
"""
from __future__ import annotations

import threading
import time
import traceback
from typing import Callable

from .action_base import ActionBase, ActionContext
from .umrf import GraphSpec, NodeSpec

# Node states (UMRF names, plus CANCELLED for nodes that never started).
WAITING = 'WAITING'
RUNNING = 'RUNNING'
STOP_REQUESTED = 'STOP_REQUESTED'
FINISHED = 'FINISHED'
FAILED = 'FAILED'
CANCELLED = 'CANCELLED'
TERMINAL = (FINISHED, FAILED, CANCELLED)


class NodeRun:
    """The run-time state of one node."""

    def __init__(self, spec: NodeSpec, indexed):
        self.spec = spec
        self.indexed = indexed              # IndexedAction (descriptor + class), fixed at graph start
        self.state = WAITING
        self.message = ''
        self.inputs = dict(spec.inputs)
        self.explicit = set(spec.inputs)    # inputs given in the graph win over parents' outputs
        self.released = False               # children may start
        self.stop_reason = ''               # why a stop was requested
        self.action: ActionBase | None = None
        self.thread: threading.Thread | None = None
        self.started_at = None
        self.ended_at = None

    @property
    def key(self) -> str:
        return self.spec.key

    def to_json(self) -> dict:
        return {'name': self.spec.name, 'instance_id': self.spec.instance_id, 'state': self.state,
                'message': self.message, 'inputs': self.inputs,
                'outputs': self.action.outputs if self.action else {},
                'effect': self.indexed.descriptor.effect,
                'parents': sorted(self.spec.parents), 'children': list(self.spec.children)}


class GraphRun:
    """A graph being executed. All state changes happen under one lock; actions run outside it."""

    def __init__(self, spec: GraphSpec, index, make_context: Callable[[NodeRun, 'GraphRun'], ActionContext],
                 on_event: Callable[[dict], None] = lambda ev: None,
                 on_finished: Callable[['GraphRun'], None] = lambda g: None):
        self.spec = spec
        self.name = spec.name
        self._make_context = make_context
        self._on_event = on_event
        self._on_finished = on_finished
        self._lock = threading.RLock()
        self._done = threading.Condition(self._lock)
        self.stopping = False
        self.finished = False
        self.failure = ''                   # the first node failure: the graph's reason
        self.started_at = time.time()
        self.nodes: dict[str, NodeRun] = {}
        for key, n in spec.nodes.items():
            indexed = index.action(n.name)
            if indexed is None:
                raise KeyError('action %r is not indexed' % n.name)
            self.nodes[key] = NodeRun(n, indexed)

    # ------------------------------------------------------------------ public
    def start(self) -> None:
        self._emit_graph('graph_started')
        with self._lock:
            for node in self.nodes.values():
                self._try_start(node)
            self._check_finished()

    def stop(self, timeout: float = 10.0) -> list[str]:
        """Stop every node; wait up to ``timeout`` s for them to end. Returns keys still running."""
        with self._lock:
            self.stopping = True
            for node in self.nodes.values():
                if node.state == WAITING:
                    self._set_state(node, CANCELLED, 'graph stopped')
                elif node.state == RUNNING:
                    self._request_stop(node)
            self._check_finished()
        return self.wait(timeout)

    def stop_node(self, key: str, timeout: float = 10.0) -> bool:
        """Stop one node; True when it ended within ``timeout``."""
        with self._lock:
            node = self.nodes[key]
            if node.state == WAITING:
                self._set_state(node, CANCELLED, 'stopped before it started')
                self._cancel_descendants(node)
                self._check_finished()
            elif node.state == RUNNING:
                self._request_stop(node)
            deadline = time.monotonic() + timeout
            while node.state not in TERMINAL:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._done.wait(left)
            return True

    def wait(self, timeout: float) -> list[str]:
        """Wait until every node is terminal; returns the keys of nodes still not done."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while not self.finished:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._done.wait(left)
            return [k for k, n in self.nodes.items() if n.state not in TERMINAL]

    def running_nodes(self) -> list[NodeRun]:
        with self._lock:
            return [n for n in self.nodes.values() if n.state == RUNNING]

    @property
    def state(self) -> str:
        with self._lock:
            if not self.finished:
                return 'STOPPING' if self.stopping else 'RUNNING'
            return FAILED if self.failure else FINISHED

    def to_json(self) -> dict:
        with self._lock:
            return {'graph_name': self.name, 'graph_description': self.spec.description,
                    'state': self.state, 'reason': self.failure, 'started_at': self.started_at,
                    'nodes': [n.to_json() for n in self.nodes.values()]}

    # ------------------------------------------------------------------ internals (lock held)
    def _emit_graph(self, kind: str, **fields) -> None:
        ev = {'event': kind, 'graph': self.name}
        ev.update(fields)
        self._on_event(ev)

    def _set_state(self, node: NodeRun, state: str, message: str = '') -> None:
        node.state = state
        node.message = message
        self._on_event({'event': 'state', 'graph': self.name, 'action': node.spec.name,
                        'instance_id': node.spec.instance_id, 'state': state, 'message': message})
        self._done.notify_all()

    def _request_stop(self, node: NodeRun, reason: str = 'stopped') -> None:
        node.stop_reason = reason
        self._set_state(node, STOP_REQUESTED, 'stop requested' if reason == 'stopped' else reason)
        if node.action is not None:
            node.action.request_stop()

    def _fail(self, node: NodeRun, error: str) -> None:
        """A node failed, and so does the graph: the nodes running now are stopped, and the children
        that require this node are cancelled."""
        self._set_state(node, FAILED, error)
        if not self.failure:
            self.failure = '%s failed: %s' % (node.key, error)
        for other in self.nodes.values():
            tolerates = other.spec.parents.get(node.key) is False      # declared this parent optional
            if other.state == RUNNING and not tolerates:
                self._request_stop(other, 'stopped: %s failed' % node.key)
        self._cancel_descendants(node)

    def _missing_inputs(self, node: NodeRun) -> list[str]:
        desc = node.indexed.descriptor
        return [k for k, p in desc.inputs.items()
                if p.required and k not in node.inputs and p.default is None]

    def _try_start(self, node: NodeRun) -> None:
        if node.state != WAITING or self.stopping:
            return
        for pkey, required in node.spec.parents.items():
            parent = self.nodes[pkey]
            if required and not parent.released:
                if parent.state in TERMINAL:
                    self._cancel(node, 'required parent %s ended without releasing it (%s)'
                                 % (pkey, parent.state.lower()))
                return
        if self._missing_inputs(node):
            if all(self.nodes[p].released or self.nodes[p].state in TERMINAL for p in node.spec.parents):
                self._cancel(node, 'input(s) %s never arrived' % ', '.join(self._missing_inputs(node)))
            return
        desc = node.indexed.descriptor
        for k, p in desc.inputs.items():
            if k not in node.inputs and p.default is not None:
                node.inputs[k] = p.default
            if k in node.inputs:
                err = p.check(node.inputs[k])
                if err:
                    self._fail(node, err)
                    return
        node.started_at = time.time()
        self._set_state(node, RUNNING)
        node.thread = threading.Thread(target=self._run_node, args=(node,), daemon=True,
                                       name='action-%s-%s' % (self.name, node.key))
        node.thread.start()

    def _cancel(self, node: NodeRun, reason: str) -> None:
        self._set_state(node, CANCELLED, reason)
        self._cancel_descendants(node)

    def _cancel_descendants(self, node: NodeRun) -> None:
        for ckey in node.spec.children:
            child = self.nodes[ckey]
            if child.state == WAITING:
                self._try_start(child)     # cancels it if it depended on this node

    def _release(self, node: NodeRun) -> None:
        """Outputs are ready: hand them to the children and start those that can start."""
        node.released = True
        outputs = node.action.outputs if node.action else {}
        for ckey in node.spec.children:
            child = self.nodes[ckey]
            cdesc = child.indexed.descriptor
            for k, v in outputs.items():
                if k in cdesc.inputs and k not in child.explicit:
                    child.inputs[k] = v
            self._try_start(child)

    def _check_finished(self) -> None:
        if not self.finished and all(n.state in TERMINAL for n in self.nodes.values()):
            self.finished = True
            self._done.notify_all()
            self._emit_graph('graph_finished', state=self.state, reason=self.failure)
            threading.Thread(target=self._on_finished, args=(self,), daemon=True).start()

    # ------------------------------------------------------------------ node thread
    def _run_node(self, node: NodeRun) -> None:
        error = None
        action = None
        entered = False
        try:
            ctx = self._make_context(node, self)
            action = node.indexed.cls(ctx)
            with self._lock:
                node.action = action
                if node.state == STOP_REQUESTED:
                    action.request_stop()
            if not action.action_ok():
                return          # stopped before it began (the finally block records it)
            entered = True
            action.on_start()
            asynchronous = node.indexed.descriptor.asynchronous
            if asynchronous and action.action_ok():
                with self._lock:
                    self._release(node)
            action.execute()
            if not asynchronous and action.action_ok():
                with self._lock:
                    self._release(node)
            error = action.failure
        except Exception as e:
            error = str(e) or type(e).__name__
            if action is not None:
                action.log_err('failed: %s\n%s' % (error, traceback.format_exc()))
        finally:
            if action is not None:
                if entered:
                    try:
                        action.on_stop()
                    except Exception as e:
                        action.log_err('on_stop failed: %s' % e)
                        error = error or 'on_stop failed: %s' % e
                problems = action.release_resources()
                if problems and not error:
                    error = 'releasing resources: ' + '; '.join(problems)
            if action is not None and not error:
                error = action.failure      # set by fail(), maybe while it was being stopped
            with self._lock:
                node.ended_at = time.time()
                stopped = node.state == STOP_REQUESTED
                if error:
                    self._fail(node, error)
                else:
                    self._set_state(node, FINISHED, (node.stop_reason or 'stopped') if stopped else '')
                for ckey in node.spec.children:
                    child = self.nodes[ckey]
                    if child.state == WAITING:
                        self._try_start(child)
                self._check_finished()
