#!/usr/bin/env python3
"""Graph start benchmark: what running each graph in a worker process costs a graph's start.

Two engine nodes run side by side on one master, with the same one-node plugin (a synchronous
action that sets an output): one runs graphs as threads in the engine (``~isolate_graphs:
false``, the design before isolation), the other in worker processes with one spare started
ahead (the default). Graphs go to each in turn, so machine load hits both alike. Measured from
the ``start_graph`` call to the node's RUNNING event and to the graph's ``graph_finished`` event
on the engine's events topic, as an operator's tool would see them. An operator does not fire
graphs back to back, so each start waits for the spare to be started again (the pool's own
pace: each start waits until a worker not used yet is registered); a burst of graphs faster than
that waits for workers to start (about 0.5 to 1 s each).

Prints a markdown table and writes bench/results/action_start.json.
Usage: python bench/bench_action_start.py [--graphs N]
"""
import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from common import pct  # noqa: E402

from temoto_testing.action_engine import write_plugin  # noqa: E402
from temoto_testing import ProcessGroupLauncher, RosMaster  # noqa: E402
from temoto_core.wait import wait_for  # noqa: E402

MODES = {'thread': False, 'worker': True}       # mode -> ~isolate_graphs
EMIT = '''
from temoto_action_engine.action_base import ActionBase

class Emit(ActionBase):
    def execute(self):
        self.set_output('value', self.input('tag'))
'''
GOAL_P95_S = 0.25      # start_graph to the node RUNNING, in a worker


class Events:
    def __init__(self, rospy, ns):
        from std_msgs.msg import String
        self.lock = threading.Lock()
        self.seen = {}                      # (graph, kind) -> monotonic time
        self.sub = rospy.Subscriber('/%s/action_engine/events' % ns, String, self._on)

    def _on(self, msg):
        ev = json.loads(msg.data)
        kind = ev.get('event') if ev.get('event') != 'state' else 'state_' + ev.get('state', '')
        with self.lock:
            self.seen.setdefault((ev.get('graph'), kind), time.monotonic())

    def when(self, graph, kind):
        with self.lock:
            return self.seen.get((graph, kind))


def spare_workers():
    """The worker nodes of the isolating engine registered now."""
    import rosnode
    return {n for n in rosnode.get_node_names() if n.startswith('/engine_worker_worker_')}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--graphs', type=int, default=30)
    opts = p.parse_args()
    work = tempfile.mkdtemp(prefix='bench_action_start_')
    plugins = os.path.join(work, 'plugins')
    write_plugin(plugins, 'emit', EMIT, inputs={'tag': {'pvf_type': 'string'}}, outputs={'value': {'pvf_type': 'string'}})
    ros = RosMaster(work).start()
    saved = ros.point_this_process()
    launcher = ProcessGroupLauncher(ros.env, work)
    import rospy
    from temoto_action_engine.srv import StartGraph
    rospy.init_node('bench_action_start', disable_signals=True)
    running = {m: [] for m in MODES}
    finished = {m: [] for m in MODES}
    try:
        events, start = {}, {}
        for mode, isolate in MODES.items():
            ns = 'bstart_' + mode
            launcher.node('temoto_action_engine', 'temoto_action_engine', name='engine_' + mode,
                          params={'temoto_namespace': ns, 'action_paths': plugins, 'isolate_graphs': isolate})
            rospy.wait_for_service('/%s/action_engine/start_graph' % ns, timeout=30)
            events[mode] = Events(rospy, ns)
            start[mode] = rospy.ServiceProxy('/%s/action_engine/start_graph' % ns, StartGraph, persistent=True)
            wait_for(lambda: events[mode].sub.get_num_connections() > 0, 20, 'events of %s' % mode)
        used = set()
        for i in range(opts.graphs):
            # the state an operator meets: the pool has started its next spare (a worker not used yet)
            used.add(wait_for(lambda: next(iter(spare_workers() - used), None), 30, 'a spare worker'))
            for mode in MODES:
                name = 'g%d' % i
                graph = {'graph_name': name, 'actions': [{'name': 'emit', 'input_parameters': {
                    'tag': {'pvf_type': 'string', 'pvf_value': str(i)}}}]}
                t0 = time.monotonic()
                resp = start[mode](graph_json=json.dumps(graph), text='')
                if resp.code != 0:
                    raise RuntimeError('%s: %s' % (mode, resp.message))
                t_end = wait_for(lambda: events[mode].when(name, 'graph_finished'), 30, '%s %s finished' % (mode, name))
                running[mode].append(events[mode].when(name, 'state_RUNNING') - t0)
                finished[mode].append(t_end - t0)
            print('  graph %2d/%d: thread %.0f ms, worker %.0f ms to RUNNING' % (
                i + 1, opts.graphs, running['thread'][-1] * 1e3, running['worker'][-1] * 1e3), flush=True)
    finally:
        rospy.signal_shutdown('bench over')
        launcher.stop_all()
        ros.stop()
        ros.restore_process(saved)
    res = {m: {'running_median_ms': statistics.median(running[m]) * 1e3, 'running_p95_ms': pct(running[m], 95) * 1e3,
               'finished_median_ms': statistics.median(finished[m]) * 1e3, 'finished_p95_ms': pct(finished[m], 95) * 1e3,
               'n': len(running[m])} for m in MODES}
    ratio = statistics.median(running['worker']) / statistics.median(running['thread'])
    res['ratio_worker_over_thread_running'] = ratio
    res['time'] = time.time()
    print()
    print('| start_graph to ... (n=%d each, alternating) | thread in the engine (before) | worker process (now) | '
          'goal |' % opts.graphs)
    print('| --- | --- | --- | --- |')
    print('| the node RUNNING, median / p95 | %.0f / %.0f ms | %.0f / %.0f ms | p95 <= %.0f ms |' % (
        res['thread']['running_median_ms'], res['thread']['running_p95_ms'], res['worker']['running_median_ms'],
        res['worker']['running_p95_ms'], GOAL_P95_S * 1e3))
    print('| the graph finished, median / p95 | %.0f / %.0f ms | %.0f / %.0f ms | |' % (
        res['thread']['finished_median_ms'], res['thread']['finished_p95_ms'], res['worker']['finished_median_ms'],
        res['worker']['finished_p95_ms']))
    print('| ratio of medians (to RUNNING), worker / thread | | %.1f | the price of isolation, shown |' % ratio)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'action_start.json'), 'w') as f:
        json.dump(res, f, indent=2, sort_keys=True)
    return 0 if res['worker']['running_p95_ms'] <= GOAL_P95_S * 1e3 else 1


if __name__ == '__main__':
    sys.exit(main())
