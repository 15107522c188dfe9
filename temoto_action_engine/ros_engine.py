"""The ROS face of the action engine: parameters, topics and services around ActionEngine.

Topics (``<ns>`` is the TeMoto namespace, param ``~temoto_namespace``, default ``temoto``):
- ``/<ns>/human_chatter``          std_msgs/String, in: instructions (wake word if ``~wake_words``)
- ``/<ns>/action_engine/feedback`` std_msgs/String, out: short sentences for the operator
- ``/<ns>/action_engine/events``   std_msgs/String, out: one JSON object per state change
- ``/<ns>/halt`` (and each robot's) std_msgs/String, out: "stop" for every motion node (temoto_core/halt.py)
Services:
- ``/<ns>/action_engine/start_graph``  StartGraph (UMRF graph JSON, or text to ground)
- ``/<ns>/action_engine/stop_graph``   StopGraph
- ``/<ns>/action_engine/list_graphs``  ListGraphs
- ``/<ns>/action_engine/list_actions`` ListActions (``reindex`` scans the folders again)
Parameters besides the namespace: ``~action_paths``, ``~wake_words``, ``~actions`` (per-action
settings), ``~include_bundled_actions``, ``~stop_timeout_s`` (15: the grace a stopped graph gets
before its worker is ended), ``~isolate_graphs`` (true: each graph in a worker process of its
own), ``~spare_workers`` (1: workers started ahead, so a graph starts without waiting) and
``~motion_wake_phrase`` ("robot please": an instruction heard on ``human_chatter``, where speech says what it
heard, that asks for a motion action must open with it; a typed one through ``start_graph`` may),
``~journal`` (a path, or ``auto``; default none): with it, graphs that were running when the engine
died are reported FAILED by its next start (``lost_graphs.py``).
"""
from __future__ import annotations

import json
import threading
import time

import rospy
from std_msgs.msg import String
from temoto_core import params, rospy_internals
from temoto_core.halt import HALT_TYPE, halt_topic
from temoto_core.node import after_init_node, clear_stale_registration, on_signals
from temoto_core.rr.journal import Journal
from temoto_core.rr.settings import journal_param

from .engine import ActionEngine
from .indexer import ActionIndex
from .isolation import TERM_GRACE_S, WorkerPool
from .lost_graphs import GraphRecords
from .srv import (ListActions, ListActionsResponse, ListGraphs, ListGraphsResponse, StartGraph, StartGraphResponse,
                  StopGraph, StopGraphResponse)
from .umrf import UmrfError

MAX_TEXT = 2000            # characters of an instruction
LISTENER_WAIT_S = 3.0      # s a restarted engine waits for listeners before it reports the graphs it lost
MAX_GRAPH_JSON = 1 << 20   # bytes of a graph


class ActionEngineNode:
    def __init__(self):
        self.namespace = params.text('temoto_namespace', 'temoto').strip('/') or 'temoto'
        paths = params.strings('action_paths', [], separator=':')
        wake = params.strings('wake_words', [])
        actions_cfg = rospy.get_param('~actions', {}) or {}
        if not isinstance(actions_cfg, dict):
            raise ValueError('parameter ~actions must map action names to their settings')
        self.stop_timeout = params.number('stop_timeout_s', 15.0, above=0)
        base = '/%s/action_engine' % self.namespace
        self.feedback_pub = rospy.Publisher(base + '/feedback', String, queue_size=50)
        self.events_pub = rospy.Publisher(base + '/events', String, queue_size=200)
        # "stop" reaches the motion nodes of this namespace and of every robot namespace an action names for its
        # Robot Manager (two hosts): publishers made now, so the first halt finds its subscribers connected
        halt_namespaces = [self.namespace] + [
            str(cfg['manager_namespaces'].get('robot_manager', '')).strip('/') for cfg in actions_cfg.values()
            if isinstance(cfg, dict) and isinstance(cfg.get('manager_namespaces'), dict)]
        self.halt_pubs = [rospy.Publisher(halt_topic(ns), HALT_TYPE, queue_size=5, tcp_nodelay=True)
                          for ns in dict.fromkeys(n for n in halt_namespaces if n)]
        motion_wake = params.strings('motion_wake_phrase', ['robot', 'please'], separator=' ')
        index = ActionIndex(paths, include_bundled=params.flag('include_bundled_actions', True))
        workers = None
        if params.flag('isolate_graphs', True):
            workers = WorkerPool(self.namespace, self.stop_timeout, spares=params.number('spare_workers', 1, minimum=0, maximum=8,
                                                                                    integer=True))
        journal = journal_param()
        self.journal = Journal(journal, run_id=str(rospy.get_param('/run_id', ''))) if journal else None
        self.engine = ActionEngine(index, namespace=self.namespace, wake_words=wake, action_config=actions_cfg,
                                   publish_event=self._publish_event, publish_feedback=self._publish_feedback,
                                   workers=workers, records=GraphRecords(self.journal) if self.journal else None,
                                   publish_halt=self._publish_halt, motion_wake=tuple(motion_wake))
        if self.engine.lost:
            threading.Thread(target=self._report_lost, name='report-lost-graphs', daemon=True).start()
        self.engine.reindex()
        self._services = [
            rospy.Service(base + '/start_graph', StartGraph, self._start_graph),
            rospy.Service(base + '/stop_graph', StopGraph, self._stop_graph),
            rospy.Service(base + '/list_graphs', ListGraphs, self._list_graphs),
            rospy.Service(base + '/list_actions', ListActions, self._list_actions),
        ]
        self._chatter = rospy.Subscriber('/%s/human_chatter' % self.namespace, String, self._on_chatter,
                                         queue_size=20)
        rospy.loginfo('action engine ready in /%s: %d action(s), %d plugin problem(s), wake words: %s'
                      % (self.namespace, len(index), len(index.problems), ', '.join(wake) or 'none'))

    def _report_lost(self) -> None:
        # a listener (a recorder, the operator's console) reconnects to a restarted engine within a moment;
        # the listing keeps the graphs FAILED whoever hears this
        deadline = time.monotonic() + LISTENER_WAIT_S
        while time.monotonic() < deadline and not (self.events_pub.get_num_connections() and
                                                   self.feedback_pub.get_num_connections()):
            time.sleep(0.05)
        self.engine.report_lost(self.stop_timeout + TERM_GRACE_S)

    # ------------------------------------------------------------------ outputs
    def _publish_feedback(self, text: str) -> None:
        self.feedback_pub.publish(String(data=text))

    def _publish_halt(self, reason: str) -> None:
        for pub in self.halt_pubs:
            pub.publish(HALT_TYPE(data=reason))

    def _publish_event(self, ev: dict) -> None:
        ev = dict(ev, stamp=rospy.get_time())
        self.events_pub.publish(String(data=json.dumps(ev, sort_keys=True, default=str)))

    # ------------------------------------------------------------------ inputs
    def _on_chatter(self, msg) -> None:
        text = msg.data
        if not text.strip():
            return
        if len(text) > MAX_TEXT:
            self._publish_feedback('ignored an instruction of %d characters (at most %d)' % (len(text), MAX_TEXT))
            return
        self.engine.say(text, require_motion_wake=True)

    def _start_graph(self, req):
        has_json, has_text = bool(req.graph_json.strip()), bool(req.text.strip())
        if has_json == has_text:
            return StartGraphResponse(code=1, message='give exactly one of graph_json and text')
        if has_text:
            if len(req.text) > MAX_TEXT:
                return StartGraphResponse(code=1, message='text is longer than %d characters' % MAX_TEXT)
            result, run = self.engine.say(req.text, use_wake_words=False)
            if run is None:
                return StartGraphResponse(code=1, message=result.message)
            return StartGraphResponse(code=0, message=result.message, graph_name=run.name,
                                      graph_json=json.dumps(run.spec.to_json(self.engine.index)))
        if len(req.graph_json) > MAX_GRAPH_JSON:
            return StartGraphResponse(code=1, message='graph_json is larger than %d bytes' % MAX_GRAPH_JSON)
        try:
            run = self.engine.start_graph(req.graph_json)
        except (UmrfError, RuntimeError) as e:
            return StartGraphResponse(code=1, message=str(e))
        return StartGraphResponse(code=0, message='graph %s started' % run.name, graph_name=run.name,
                                  graph_json=json.dumps(run.spec.to_json(self.engine.index)))

    def _stop_graph(self, req):
        if not req.graph_name.strip():
            return StopGraphResponse(code=1, message='graph_name is empty')
        ok, message = self.engine.stop_graph(req.graph_name.strip(), self.stop_timeout)
        return StopGraphResponse(code=0 if ok else 1, message=message)

    def _list_graphs(self, req):
        return ListGraphsResponse(json=json.dumps(self.engine.list_graphs(), default=str))

    def _list_actions(self, req):
        data = self.engine.reindex() if req.reindex else self.engine.index.to_json()
        return ListActionsResponse(json=json.dumps(data, default=str))

    # ------------------------------------------------------------------ lifetime
    def shutdown(self) -> None:
        """Stop every graph while rospy still works, so each action's registrar can unload remotely."""
        self._chatter.unregister()
        self.engine.shutdown(self.stop_timeout)
        for s in self._services:
            s.shutdown()
        if self.journal is not None:
            self.journal.close()


def run_node(name: str = 'temoto_action_engine') -> None:
    """Entry of the node script: signals stop the graphs first, then rospy."""
    clear_stale_registration(name)
    rospy_internals.install_bounded_handshake()
    rospy_internals.install_shutdown_guard()
    rospy.init_node(name, disable_signals=True)
    # the station's engine outlives a master on a robot that lost power: it registers again (node.py)
    after_init_node()
    node = ActionEngineNode()
    stop = threading.Event()
    on_signals(lambda signum: stop.set())     # from a thread: Event.set in a handler can deadlock
    while not stop.is_set() and not rospy.is_shutdown():
        stop.wait(1.0)
    rospy.loginfo('action engine shutting down: stopping running graphs')
    node.shutdown()
    rospy.signal_shutdown('action engine stopped')
