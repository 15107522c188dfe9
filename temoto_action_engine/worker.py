"""A graph worker: one process, one ROS node, one running graph.

Why: an action plugin is code the engine does not control. Run in the engine's own process, a
plugin that calls ``os._exit`` or crashes in C takes the engine and every other graph with it,
and one that ignores a stop keeps its resources for as long as the engine lives. Here each
graph runs in a process of its own (see ``isolation.py`` for the engine's side). The engine
survives such a plugin, reports its graph FAILED with the reason, and can end a worker that
does not stop. What the worker held is released by the managers once the worker's node is
gone, as for any consumer that dies.

The worker talks to the engine over its stdin and stdout (``worker_protocol``). Plugins print
to stdout, so that stream is moved aside before any plugin is loaded and stdout is pointed at
stderr. When the engine goes away (its end of the pipe closes), the graph is stopped, its
resources released, and the worker exits.
"""
from __future__ import annotations

import argparse
import itertools
import os
import signal
import sys
import threading
import traceback
from typing import IO

import rospy
from temoto_core import rospy_internals
from temoto_core.node import on_signals, prime_log_parameter

from . import worker_protocol as wp
from .action_base import ActionContext, ActionError, default_rr_factory
from .graph import GraphRun, NodeRun
from .indexer import IndexedAction, load_plugin
from .umrf import UmrfError, parse_graph

ABORT_RELEASE_S = 3.0      # s a stop signal leaves for releasing what the graph holds
REQUEST_MARGIN_S = 10.0    # s an engine request may take beyond the stop timeout it was given


class PluginSet:
    """The plugins one graph needs, loaded from the descriptor files the engine indexed.

    A mapping name -> descriptor for ``parse_graph``, plus ``action(name)`` for ``GraphRun``, as
    ``ActionIndex`` offers, without scanning any folder.
    """

    def __init__(self, paths: dict[str, str]):
        self._actions: dict[str, IndexedAction] = {}
        problems = []
        for name, path in sorted(paths.items()):
            action, problem = load_plugin(path)
            if problem:
                problems.append(str(problem))
            elif action.name != name:
                problems.append('%s now defines action %r, not %r' % (path, action.name, name))
            else:
                self._actions[name] = action
        if problems:
            raise UmrfError('<plugins>', problems)

    def get(self, name: str):
        a = self._actions.get(name)
        return a.descriptor if a else None

    def __contains__(self, name) -> bool:
        return name in self._actions

    def action(self, name: str) -> IndexedAction | None:
        return self._actions.get(name)


class EngineLink:
    """What an action sees as ``self.engine`` in a worker: the engine's answers, over the pipe."""

    def __init__(self, out: wp.LineWriter, graph_name: str, stop_timeout: float):
        self._out = out
        self._graph = graph_name
        self._stop_timeout = stop_timeout
        self._ids = itertools.count(1)
        self._cond = threading.Condition()
        self._replies: dict[int, dict] = {}
        self._closed = False

    def _ask(self, op: str, wait_s: float, **fields):
        rid = next(self._ids)
        if not self._out.send(kind=wp.REQUEST, id=rid, op=op, **fields):
            raise ActionError('the action engine is gone')
        with self._cond:
            if not self._cond.wait_for(lambda: rid in self._replies or self._closed, wait_s):
                raise ActionError('the action engine did not answer %s within %.0f s' % (op, wait_s))
            if rid not in self._replies:
                raise ActionError('the action engine is gone')
            reply = self._replies.pop(rid)
        if reply.get('error'):
            raise ActionError(str(reply['error']))
        return reply.get('result')

    def deliver(self, msg: dict) -> None:
        with self._cond:
            self._replies[int(msg.get('id', 0))] = msg
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def stop_actions(self, target: str, exclude_graph: str | None = None, timeout: float | None = None,
                     motion_only: bool = False) -> list[str]:
        timeout = self._stop_timeout if timeout is None else timeout
        return list(self._ask('stop_actions', timeout + REQUEST_MARGIN_S, target=target,
                              exclude_graph=exclude_graph or self._graph, timeout=timeout,
                              motion_only=motion_only) or [])

    def halt(self, reason: str) -> None:
        self._ask('halt', REQUEST_MARGIN_S, reason=reason)

    def running_actions(self, exclude_graph: str | None = None) -> list[str]:
        return list(self._ask('running_actions', REQUEST_MARGIN_S,
                              exclude_graph=exclude_graph or self._graph) or [])


class GraphWorker:
    """Runs the graph the engine sends, and reports everything that happens back to it."""

    def __init__(self, out: wp.LineWriter, namespace: str, stop_timeout: float):
        self.out = out
        self.namespace = namespace
        self.stop_timeout = stop_timeout
        self.run: GraphRun | None = None
        self.link: EngineLink | None = None
        self.done = threading.Event()
        self._config: dict = {}
        self._uids = itertools.count(1)
        self._rr_factory = default_rr_factory(namespace)

    # ------------------------------------------------------------------ engine -> worker
    def handle(self, msg: dict) -> None:
        op = msg.get('op')
        if op == wp.RUN and self.run is None:
            self._start(msg)
        elif op == wp.STOP and self.run is not None:
            threading.Thread(target=self.run.stop, args=(self.stop_timeout,), daemon=True).start()
        elif op == wp.STOP_NODE and self.run is not None and msg.get('key') in self.run.nodes:
            threading.Thread(target=self.run.stop_node, args=(msg['key'], self.stop_timeout),
                             daemon=True).start()
        elif op == wp.REPLY and self.link is not None:
            self.link.deliver(msg)
        else:
            rospy.logwarn('graph worker: ignored a message it cannot act on: %r' % (op,))

    def engine_gone(self) -> None:
        """The engine's end of the pipe closed: stop the graph and let it release what it holds."""
        if self.link is not None:
            self.link.close()
        if self.run is None:
            self.done.set()
            return
        rospy.logwarn('graph worker: the action engine is gone; stopping graph %s' % self.run.name)
        self.run.stop(self.stop_timeout)
        self.done.set()

    def _start(self, msg: dict) -> None:
        try:
            plugins = PluginSet(dict(msg.get('plugins') or {}))
            spec = parse_graph(msg.get('graph'), plugins)
        except UmrfError as e:
            self.out.send(kind=wp.REFUSED, message=str(e))
            self.done.set()
            return
        self._config = dict(msg.get('config') or {})
        self.link = EngineLink(self.out, spec.name, self.stop_timeout)
        self.run = GraphRun(spec, plugins, self._make_context, self._on_event, lambda run: self.done.set())
        self.run.start()
        # the nodes that could start are RUNNING now: the engine answers start_graph once it has this
        self.out.send(kind=wp.SNAPSHOT, graph=self.run.to_json(), started=True)

    # ------------------------------------------------------------------ worker -> engine
    def _on_event(self, ev: dict) -> None:
        self.out.send(kind=wp.EVENT, event=ev)
        if ev.get('event') == 'state' and self.run is not None:
            self.out.send(kind=wp.SNAPSHOT, graph=self.run.to_json())

    def _publish_event(self, ev: dict) -> None:
        self.out.send(kind=wp.EVENT, event=ev)

    def _publish_feedback(self, text: str) -> None:
        self.out.send(kind=wp.FEEDBACK, text=text)

    def _make_context(self, node: NodeRun, run: GraphRun) -> ActionContext:
        return ActionContext(
            descriptor=node.indexed.descriptor, instance_id=node.spec.instance_id, graph_name=run.name,
            inputs=dict(node.inputs), uid='%d_%d' % (os.getpid(), next(self._uids)),
            config=dict(self._config.get(node.spec.name, {}) or {}), namespace=self.namespace,
            rr_factory=self._rr_factory, publish_event=self._publish_event,
            publish_feedback=self._publish_feedback, engine=self.link)

    # ------------------------------------------------------------------ the end
    def finish(self) -> None:
        if self.run is not None:
            self.out.send(kind=wp.FINISHED, graph=self.run.to_json())

    def release_all(self) -> None:
        """A stop signal: the engine is ending a graph that did not stop. Release what can be released."""
        if self.run is None:
            return
        for node in list(self.run.nodes.values()):
            if node.action is not None:
                node.action.release_resources()


def _read_commands(stream: IO[bytes], worker: GraphWorker) -> None:
    for line in iter(stream.readline, b''):
        msg = wp.decode(line)
        if msg is None:
            rospy.logerr('graph worker: a line from the engine is not a JSON object: %r' % line[:200])
            continue
        try:
            worker.handle(msg)
        except Exception as e:      # a bug here must end the graph with a reason, not wedge the worker
            rospy.logerr('graph worker: handling %r failed: %s\n%s' % (msg.get('op'), e, traceback.format_exc()))
            if worker.run is None:
                worker.out.send(kind=wp.REFUSED, message='the worker failed to start it: %s' % e)
                worker.done.set()
    worker.engine_gone()


def _protocol_stdout() -> IO[bytes]:
    """The real stdout, kept for the protocol; fd 1 (``print`` in a plugin) now goes to stderr."""
    sys.stdout.flush()
    proto = os.fdopen(os.dup(1), 'wb')
    os.dup2(2, 1)
    return proto


def _abort(worker: GraphWorker, signum: int) -> None:
    """SIGTERM or SIGINT from the engine: release within a bound, then exit whatever a plugin does."""
    releaser = threading.Thread(target=worker.release_all, daemon=True)
    releaser.start()
    releaser.join(ABORT_RELEASE_S)
    os._exit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description='Run one action graph for the TeMoto action engine '
                                            '(started by the engine; talks to it over stdin and stdout).')
    p.add_argument('--node-name', required=True)
    p.add_argument('--temoto-namespace', default='temoto')
    p.add_argument('--stop-timeout', type=float, default=15.0)
    args = p.parse_args(rospy.myargv(argv if argv is not None else sys.argv)[1:])
    out = wp.LineWriter(_protocol_stdout())
    worker = GraphWorker(out, args.temoto_namespace, args.stop_timeout)
    on_signals(lambda signum: _abort(worker, signum), (signal.SIGTERM, signal.SIGINT))
    rospy_internals.install_bounded_handshake()
    rospy_internals.install_shutdown_guard()
    rospy.init_node(args.node_name, disable_signals=True)
    prime_log_parameter()      # its logging must not wait for the master (node.py)
    out.send(kind=wp.READY, pid=os.getpid(), node=rospy.get_name())
    threading.Thread(target=_read_commands, args=(sys.stdin.buffer, worker), daemon=True,
                     name='engine-pipe').start()
    worker.done.wait()
    worker.finish()
    out.close()
    rospy.signal_shutdown('graph finished')
    # a plugin's leftover non-daemon thread must not keep a finished worker (and its node) alive
    os._exit(0)


if __name__ == '__main__':
    main()
