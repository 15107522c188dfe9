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
    """What the operator sees of the engine: its feedback and events, and its services."""

    def __init__(self):
        from temoto_action_engine.srv import ListGraphs, StartGraph, StopGraph
        self.lock = threading.Lock()
        self.feedback, self.events = [], []
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
        with self.lock:
            self.events.append(json.loads(msg.data))

    def say(self, text: str) -> str:
        resp = self.start(text=text)
        assert resp.code == 0, resp.message
        return resp.graph_name

    def graph(self, name: str) -> dict:
        return next(g for g in json.loads(self.list().json) if g['graph_name'] == name)

    def of(self, kind: str, graph: str) -> list:
        with self.lock:
            return [e for e in self.events if e.get('event') == kind and e.get('graph') == graph]

    def wait_event(self, kind: str, graph: str, timeout: float, what: str) -> list:
        """The graph's ``kind`` events, once there is one. A graph that ends first fails the test at once
        with its reason and the events it sent, rather than as a bare timeout."""
        def seen():
            got = self.of(kind, graph)
            if not got and self.of('graph_finished', graph):
                with self.lock:
                    sent = [e for e in self.events if e.get('graph') == graph]
                raise AssertionError('the graph ended before %s: %s' % (what, sent))
            return got
        return wait_for(seen, timeout, what)

    def close(self):
        for sub in self.subs:
            sub.unregister()

    def node_state(self, graph: str, key: str) -> str | None:
        """The last state the events topic gave node ``key`` (``navigate_0``) of ``graph``."""
        with self.lock:
            states = [e['state'] for e in self.events if e.get('event') == 'state' and e.get('graph') == graph
                      and '%s_%s' % (e.get('action'), e.get('instance_id')) == key]
        return states[-1] if states else None

    def heard(self, *parts: str) -> str | None:
        """The first feedback sentence that contains every one of ``parts``."""
        with self.lock:
            return next((f for f in self.feedback if all(p in f for p in parts)), None)
