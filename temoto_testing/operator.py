"""The operator's side of the action engine, for tests across processes: its feedback and events, and its
services, as an operator reads and calls them."""
from __future__ import annotations

import json
import threading

import rospy
from std_msgs.msg import String

from temoto_core.wait import wait_for
from temoto_testing.sensor_manager import NS


class Operator:
    """What the operator sees of the engine: its feedback and events, and its services.

    A graph's name is used again by its next run ("follow_hand" each time the hand is followed), so what is
    read of a graph (``of``, ``wait_event``, ``node_state``) is its latest run's: the events since its last
    ``graph_started``. A test that starts a run waits for that run's ``graph_started`` (``wait_run``) before
    it reads, or an event of the run before could pass for one of the new run's (a CI run took an earlier
    run's "following" for the new one's, and waited for a dial the new run had not set yet).
    """

    def __init__(self):
        from temoto_action_engine.srv import ListGraphs, StartGraph, StopGraph
        self.lock = threading.Lock()
        self.feedback, self.events = [], []
        self._run_start = {}             # graph name -> index in events of its latest graph_started
        self._runs = {}                  # graph name -> how many runs of it started
        self.subs = [rospy.Subscriber('/%s/action_engine/feedback' % NS, String, self._on_feedback),
                     rospy.Subscriber('/%s/action_engine/events' % NS, String, self._on_event)]
        base = '/%s/action_engine/' % NS
        self.start = rospy.ServiceProxy(base + 'start_graph', StartGraph)
        self.stop = rospy.ServiceProxy(base + 'stop_graph', StopGraph)
        self.list = rospy.ServiceProxy(base + 'list_graphs', ListGraphs)

    def _on_feedback(self, msg):
        with self.lock:
            self.feedback.append(msg.data)

    def _on_event(self, msg):
        event = json.loads(msg.data)
        with self.lock:
            if event.get('event') == 'graph_started':
                graph = event.get('graph')
                self._run_start[graph] = len(self.events)
                self._runs[graph] = self._runs.get(graph, 0) + 1
            self.events.append(event)

    def runs(self) -> dict:
        """How many runs of each graph have started: taken before starting one, for ``wait_run``."""
        with self.lock:
            return dict(self._runs)

    def wait_run(self, graph: str, before: dict, timeout: float = 20.0) -> None:
        """Wait for a run of ``graph`` that started after ``before`` (``runs()``) was taken."""
        wait_for(lambda: self.runs().get(graph, 0) > before.get(graph, 0), timeout, 'a new run of %s' % graph)

    def _latest(self, graph: str) -> list:
        """The events of the latest run of ``graph``. Called with the lock held."""
        return [e for e in self.events[self._run_start.get(graph, 0):] if e.get('graph') == graph]

    def say(self, text: str) -> str:
        """Start a graph by text; its name, once its run has started."""
        before = self.runs()
        resp = self.start(text=text)
        assert resp.code == 0, resp.message
        self.wait_run(resp.graph_name, before)
        return resp.graph_name

    def graph(self, name: str) -> dict:
        return next(g for g in json.loads(self.list().json) if g['graph_name'] == name)

    def of(self, kind: str, graph: str) -> list:
        """The ``kind`` events of the latest run of ``graph``."""
        with self.lock:
            return [e for e in self._latest(graph) if e.get('event') == kind]

    def wait_event(self, kind: str, graph: str, timeout: float, what: str) -> list:
        """The graph's ``kind`` events, once there is one. A graph that ends first fails the test at once
        with its reason and the events it sent, rather than as a bare timeout."""
        def seen():
            got = self.of(kind, graph)
            if not got and self.of('graph_finished', graph):
                with self.lock:
                    sent = self._latest(graph)
                raise AssertionError('the graph ended before %s: %s' % (what, sent))
            return got
        return wait_for(seen, timeout, what)

    def close(self):
        for sub in self.subs:
            sub.unregister()

    def node_state(self, graph: str, key: str) -> str | None:
        """The last state the events topic gave node ``key`` (``navigate_0``) of the latest run of ``graph``."""
        with self.lock:
            states = [e['state'] for e in self._latest(graph) if e.get('event') == 'state'
                      and '%s_%s' % (e.get('action'), e.get('instance_id')) == key]
        return states[-1] if states else None

    def heard(self, *parts: str) -> str | None:
        """The first feedback sentence that contains every one of ``parts``."""
        with self.lock:
            return next((f for f in self.feedback if all(p in f for p in parts)), None)

    def wait_heard(self, timeout: float, *parts: str) -> str:
        """``heard(*parts)``, once it is. Feedback and events are two topics, each on its own connection: the
        sentence an action says as it fails may arrive after the event that it ended (a CI run)."""
        try:
            return wait_for(lambda: self.heard(*parts), timeout, 'feedback with %s' % ', '.join(map(repr, parts)))
        except TimeoutError as err:
            with self.lock:
                raise AssertionError('%s; the last feedback: %s' % (err, self.feedback[-5:])) from None
