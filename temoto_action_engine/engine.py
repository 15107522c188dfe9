"""ActionEngine: the index, the grounder and the running graphs, without any ROS wiring.

The ROS node (``ros_engine.py``) only turns topics and services into calls on this class,
so everything here is testable in-process with fake registrars.

Graphs run either in this process (``GraphRun``, one thread per node: for tests with fake
registrars) or, given a ``WorkerPool``, each in a worker process of its own (``WorkerGraph``),
which is what the node does: a plugin that crashes or ignores a stop then costs its own graph,
never the engine. Both have the same face, so nothing below depends on where a graph runs.
"""
from __future__ import annotations

import collections
import itertools
import json
import os
import threading
from typing import Any, Callable

import rospy

from .action_base import ActionContext, default_rr_factory
from .graph import FAILED, CANCELLED, GraphRun, NodeRun
from .grounding import TOKEN_RE, Grounder, inflections, word_forms
from .indexer import ActionIndex
from .isolation import WorkerGraph, WorkerPool
from .lost_graphs import GraphRecords, LostGraph, end_workers_in_background
from . import worker_protocol as wp
from .umrf import GraphSpec, UmrfError, parse_graph

EVERYTHING = {'everything', 'all', 'every', 'anything'}
STOP_ACTION = 'stop'
MOTION_WAKE = ('robot', 'please')        # the paper's "Robot please go"
# words that, said after "stop" (or alone), mean the robot: "stop", "stop stop", "stop the robot", "stop moving"
HALT_WORDS = EVERYTHING | {'stop', 'robot', 'moving', 'motion', 'now', 'right', 'driving', 'arm', 'arms', 'base'}


class ActionEngine:
    def __init__(self, index: ActionIndex, namespace: str = 'temoto', wake_words=(),
                 action_config: dict | None = None, rr_factory: Callable[[str], Any] | None = None,
                 publish_event: Callable[[dict], None] | None = None,
                 publish_feedback: Callable[[str], None] | None = None, history: int = 20,
                 interface_factories: dict | None = None, workers: WorkerPool | None = None,
                 records: GraphRecords | None = None, publish_halt: Callable[[str], None] | None = None,
                 motion_wake: tuple = MOTION_WAKE):
        self.index = index
        self.namespace = namespace
        self.wake_words = [w for w in wake_words if w]
        self.action_config = action_config or {}
        self.rr_factory = rr_factory or default_rr_factory(namespace)
        self._publish_event = publish_event or (lambda ev: None)
        self._publish_feedback = publish_feedback or (lambda text: None)
        self._publish_halt = publish_halt or (lambda reason: None)
        self.motion_wake = tuple(w.lower() for w in motion_wake if w)
        self._lock = threading.RLock()
        self._graphs: dict[str, GraphRun] = {}
        self._finished: collections.OrderedDict = collections.OrderedDict()
        self._history = history
        self.interface_factories = dict(interface_factories or {})
        self._uids = itertools.count(1)
        self._grounder = None
        self._closed = False
        self.workers = workers
        self.records = records          # running graphs, kept across a crash of the engine (lost_graphs.py)
        self.lost: list = []            # graphs an earlier incarnation left running: reported FAILED
        if records is not None:
            self.lost = records.take_lost()
            for record in self.lost:
                lost = LostGraph(record)
                self._finished[lost.name] = lost

    def report_lost(self, stop_bound: float) -> None:
        """Tell the operator about the graphs an earlier incarnation left running, and end their workers."""
        for record in self.lost:
            lost = LostGraph(record)
            rospy.logerr('graph %s: %s' % (lost.name, lost.reason))
            self._publish_event({'event': 'graph_finished', 'graph': lost.name, 'state': FAILED,
                                 'reason': lost.reason})
            self.feedback('graph %s failed: %s' % (lost.name, lost.reason))
        end_workers_in_background(self.lost, stop_bound, rospy.logwarn)

    # ------------------------------------------------------------------ index
    def reindex(self) -> dict:
        self.index.reindex()
        with self._lock:
            self._grounder = None
        for p in self.index.problems:
            rospy.logerr('action plugin problem: %s' % p)
        rospy.loginfo('indexed %d action(s): %s' % (len(self.index), ', '.join(self.index)))
        return self.index.to_json()

    def grounder(self, wake_words=None) -> Grounder:
        with self._lock:
            if self._grounder is None:
                self._grounder = Grounder(self.index.descriptors())
            g = self._grounder
        if wake_words:
            return Grounder(g.descriptors, wake_words)
        return g

    # ------------------------------------------------------------------ reporting
    def feedback(self, text: str) -> None:
        rospy.loginfo('feedback: %s' % text)
        self._publish_feedback(text)

    def _on_event(self, ev: dict) -> None:
        self._publish_event(ev)
        if ev.get('event') == 'state':
            who = '%s_%s' % (ev['action'], ev['instance_id'])
            if ev['state'] == FAILED:
                self.feedback('%s failed: %s' % (ev['action'], ev['message']))
            elif ev['state'] == CANCELLED and ev['message'] != 'graph stopped' and \
                    not ev['message'].startswith('stopped: '):
                self.feedback('%s did not start: %s' % (ev['action'], ev['message']))
            rospy.loginfo('graph %s: %s %s %s' % (ev['graph'], who, ev['state'], ev['message']))

    # ------------------------------------------------------------------ halting
    def halt(self, reason: str) -> None:
        """Every motion node hears "stop" now (``temoto_core/halt.py``), before any graph is stopped."""
        self._publish_halt(reason)
        self._publish_event({'event': 'halt', 'reason': reason})
        rospy.logwarn('halt: %s' % reason)

    @staticmethod
    def is_halt(clauses) -> bool:
        """Whether grounded ``clauses`` ask to stop the robot: "stop", "stop stop", "stop everything",
        "stop the robot". "Stop showing the environment" names an action and halts nothing."""
        if not clauses or any(c.action != STOP_ACTION for c in clauses):
            return False
        return all(ActionEngine.is_halt_target(str(c.inputs.get('action', ''))) for c in clauses)

    @staticmethod
    def is_halt_target(target: str) -> bool:
        """Whether the words after "stop" mean the robot (none, "stop", "everything", "the robot", ...)."""
        words = [w.lower().strip(".'") for w in TOKEN_RE.findall(target or '')]
        return all(w in HALT_WORDS for w in words)

    # ------------------------------------------------------------------ graphs
    def say(self, text: str, use_wake_words: bool = True, require_motion_wake: bool = False):
        """Ground an instruction and start its graph. Returns (GroundingResult, GraphRun or None).

        A stop of the robot halts every motion first, through the halt topic, and then runs its graph, which
        stops the motion actions. The motion wake phrase (``motion_wake``, "robot please") may open any
        instruction; with ``require_motion_wake`` (speech, chatter) an instruction that asks for a motion
        action must open with it, so that words said to someone else never move the robot.
        """
        spoken, woke = self.strip_motion_wake(text)
        result = self.grounder(self.wake_words if use_wake_words else None).ground(spoken)
        if not result.addressed:
            rospy.logdebug('not addressed to us: %r' % text)
            return result, None
        if not result.ok:
            self.feedback(result.message)
            return result, None
        if self.is_halt(result.clauses):
            self.halt('the operator said "%s"' % text.strip()[:80])
        elif require_motion_wake and not woke:
            moving = [c.action for c in result.clauses if self.index.descriptors()[c.action].motion]
            if moving:
                wake = ' '.join(self.motion_wake)
                result.ok, result.graph = False, None
                result.message = ('not started: %s moves the robot, so say "%s" first ("%s %s")'
                                  % (', '.join(dict.fromkeys(moving)), wake, wake, text.strip()))
                self.feedback(result.message)
                return result, None
        try:
            run = self.start_graph(result.graph)
        except (UmrfError, RuntimeError) as e:
            self.feedback('could not start "%s": %s' % (text, e))
            return result, None
        if result.unmatched or any(c.ignored for c in result.clauses):
            ignored = [w for c in result.clauses for w in c.ignored]
            self.feedback('%s; running as graph %s (ignored words: %s)'
                          % (result.message, run.name, ', '.join(ignored)))
        else:
            self.feedback('%s; running as graph %s' % (result.message, run.name))
        return result, run

    def motion_refusal(self, text: str, clauses, motion_wake: tuple) -> str:
        """Why an instruction may not start its motion actions, or ''."""
        moving = [c.action for c in clauses if self.index.descriptors()[c.action].motion]
        if not moving:
            return ''
        words = [w.lower().strip(".'") for w in TOKEN_RE.findall(text) if w not in (',', ';')]
        wake = [w.lower() for w in motion_wake]
        if self.wake_words and words and words[0] in {w.lower() for w in self.wake_words}:
            words = words[1:]
        if words[:len(wake)] == wake:
            return ''
        return ('not started: %s moves the robot, so the instruction must open with "%s" ("%s %s")'
                % (', '.join(dict.fromkeys(moving)), ' '.join(wake), ' '.join(wake), text.strip()))

    def strip_motion_wake(self, text: str) -> tuple[str, bool]:
        """``text`` without the motion wake phrase (kept after a wake word), and whether it was there."""
        tokens = text.split()
        lead = []
        if tokens and self.wake_words and tokens[0].lower().strip(',') in {w.lower() for w in self.wake_words}:
            lead, tokens = tokens[:1], tokens[1:]
        n = len(self.motion_wake)
        said = [t.lower().strip(",.!") for t in tokens[:n]]
        if n and said == list(self.motion_wake):
            return ' '.join(lead + tokens[n:]), True
        return text, False

    def start_graph(self, graph) -> GraphRun:
        """Validate a UMRF graph (JSON text or dict) and start it. Raises UmrfError, changing nothing."""
        spec: GraphSpec = parse_graph(graph, self.index)
        worker = self.workers.take() if self.workers is not None else None    # may wait for a start
        with self._lock:
            if self._closed:
                if worker is not None:
                    worker.close()
                raise RuntimeError('the engine is shutting down')
            base, n = spec.name, 1
            while spec.name in self._graphs:
                n += 1
                spec.name = '%s_%d' % (base, n)
            if worker is None:
                run = GraphRun(spec, self.index, self._make_context, self._on_event, self._graph_finished)
            else:
                run = WorkerGraph(spec, self.index, worker, dict(self.action_config), self._on_event,
                                  self.feedback, self._graph_finished, self._serve_worker_request)
            self._graphs[spec.name] = run
            self._finished.pop(spec.name, None)
        if self.records is not None:
            self.records.started(spec.name, run.to_json(), worker.proc.pid if worker is not None else 0)
        run.start()
        return run

    def _serve_worker_request(self, run: WorkerGraph, msg: dict) -> None:
        """A graph in a worker asks the engine (the ``stop`` action stops actions of other graphs)."""
        op, result, error = msg.get('op'), None, ''
        try:
            if op == 'stop_actions':
                timeout = min(max(float(msg.get('timeout', 15.0)), 0.0), 120.0)
                result = self.stop_actions(str(msg.get('target', '')), exclude_graph=run.name, timeout=timeout,
                                           motion_only=bool(msg.get('motion_only', False)))
            elif op == 'running_actions':
                result = self.running_actions(exclude_graph=run.name)
            elif op == 'halt':
                self.halt(str(msg.get('reason', ''))[:200] or 'the stop action')
                result = True
            else:
                error = 'unknown request %r' % (op,)
        except (TypeError, ValueError, RuntimeError) as e:
            error = '%s failed: %s' % (op, e)
        run.worker.send(op=wp.REPLY, id=msg.get('id'), result=result, error=error)

    def _make_context(self, node: NodeRun, run: GraphRun) -> ActionContext:
        return ActionContext(
            descriptor=node.indexed.descriptor, instance_id=node.spec.instance_id, graph_name=run.name,
            inputs=dict(node.inputs), uid='%d_%d' % (os.getpid(), next(self._uids)),
            config=dict(self.action_config.get(node.spec.name, {}) or {}), namespace=self.namespace,
            rr_factory=self.rr_factory, publish_event=self._publish_event,
            publish_feedback=self.feedback, engine=self, interface_factories=self.interface_factories)

    def _graph_finished(self, run: GraphRun) -> None:
        if self.records is not None:
            self.records.finished(run.name)
        with self._lock:
            if self._graphs.get(run.name) is run:
                del self._graphs[run.name]
                self._finished[run.name] = run
                while len(self._finished) > self._history:
                    self._finished.popitem(last=False)

    def stop_graph(self, name: str, timeout: float = 15.0) -> tuple[bool, str]:
        with self._lock:
            run = self._graphs.get(name)
            known = sorted(self._graphs)
        if run is None:
            return False, 'no running graph %r (running: %s)' % (name, ', '.join(known) or 'none')
        left = run.stop(timeout)
        if left and isinstance(run, WorkerGraph):
            return False, ('graph %s: %s did not stop within %.0f s; its worker process was ended, and what it '
                           'held is released' % (name, ', '.join(left), timeout))
        if left:
            return False, 'graph %s: %s did not stop within %.0f s' % (name, ', '.join(left), timeout)
        return True, 'graph %s stopped' % name

    def graph(self, name: str) -> GraphRun | None:
        with self._lock:
            return self._graphs.get(name) or self._finished.get(name)

    def list_graphs(self) -> list[dict]:
        with self._lock:
            runs = list(self._graphs.values()) + list(self._finished.values())
        return [r.to_json() for r in runs]

    # ------------------------------------------------------------------ actions (for `stop`)
    def _running_nodes(self, exclude_graph: str | None):
        with self._lock:
            runs = [r for n, r in self._graphs.items() if n != exclude_graph]
        return [(r, n) for r in runs for n in r.running_nodes()]

    def running_actions(self, exclude_graph: str | None = None) -> list[str]:
        return ['%s/%s' % (r.name, n.key) for r, n in self._running_nodes(exclude_graph)]

    def stop_actions(self, target: str, exclude_graph: str | None = None, timeout: float = 15.0,
                     motion_only: bool = False) -> list[str]:
        """Stop the running actions that ``target`` names best; returns 'graph/node' of those stopped.

        ``target`` may be an action name, a node key, a graph name, or the words that started the
        action ("showing the environment"); "everything"/"all" stops every running action.
        ``motion_only``: every running action that moves the robot (``motion`` in its descriptor), whatever
        the target says.
        """
        words = [w.lower().strip(".'") for w in TOKEN_RE.findall(target or '')]
        nodes = self._running_nodes(exclude_graph)
        if motion_only:
            chosen = [(r, n) for r, n in nodes if n.indexed.descriptor.motion]
        elif any(w in EVERYTHING for w in words):
            chosen = nodes
        else:
            scored = []
            for run, node in nodes:
                d = node.indexed.descriptor
                score = 0
                if target.strip() in (d.name, node.key, run.name):
                    score += 10
                verbs = set().union(*(inflections(v) for v in d.grounding.verbs)) if d.grounding.verbs else set()
                subjects = set().union(*(word_forms(s) for s in d.grounding.subjects)) if d.grounding.subjects \
                    else set()
                values = {str(v).lower() for v in node.inputs.values()}
                for w in words:
                    score += (w in verbs) + 2 * (w in subjects) + 2 * (w in values) + (w in d.name.split('_'))
                scored.append((score, run, node))
            best = max((s for s, _, _ in scored), default=0)
            chosen = [(r, n) for s, r, n in scored if s == best and best > 0]
        stopped = []
        for run, node in chosen:
            if run.stop_node(node.key, timeout):
                stopped.append('%s/%s' % (run.name, node.key))
            else:       # a worker graph was ended; an in-process one is still stopping
                stopped.append('%s/%s (did not stop within %.0f s)' % (run.name, node.key, timeout))
        return stopped

    def shutdown(self, timeout: float = 15.0) -> None:
        """Stop every graph, all at once, each within ``timeout`` s; then the spare workers."""
        with self._lock:
            self._closed = True
            runs = list(self._graphs.values())
        stoppers = [threading.Thread(target=r.stop, args=(timeout,), daemon=True) for r in runs]
        if self.workers is not None:        # the spares go meanwhile
            stoppers.append(threading.Thread(target=self.workers.shutdown, daemon=True))
        for t in stoppers:
            t.start()
        for t in stoppers:
            t.join()
        with self._lock:
            runs = list(self._graphs.values()) + list(self._finished.values())
        for r in runs:          # the engine outlives its workers: none is left behind when it exits
            if isinstance(r, WorkerGraph):
                r.reap()

    @staticmethod
    def dumps(obj) -> str:
        return json.dumps(obj, sort_keys=True, default=str)
