#!/usr/bin/env python3
"""What speaking for other nodes to a restarted master costs, measured side by side in one run.

Every TeMoto node asks the master once a second whether it knows the node and which run it is
(``temoto_core/master_rejoin.py``). The RViz host now also speaks for librviz's roscpp node, and an ER
Manager for the nodes of every process it runs: each adds one ``lookupNode`` to that same round trip.

1. The check while all is well, with no adopted node (what every node paid before) against 20 adopted
   nodes (a station ER Manager running 20 throttles), interleaved. Goal: the 20 nodes add at most 1 ms
   at p95 (the check runs once a second).
2. The pass that registers everything again after the master restarted: this node alone against this node
   and 20 adopted roscpp nodes. Goal: under 1 s for 20 nodes (the check's period: back within two).
3. Finding a process's nodes by its ports (once per process the ER Manager starts, in the background), with
   the 20 nodes and this one at the master. Goal: p95 at most 50 ms.
4. The master probe a load makes before it opens a new consumer's status channel (once per consumer).
   Goal: p95 at most 1 ms on loopback.

Prints a markdown table and writes bench/results/master_check.json.
"""
import json
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import rospy  # noqa: E402

from common import pct  # noqa: E402
from temoto_core import master_rejoin  # noqa: E402
from temoto_core.master import RosMaster, free_port  # noqa: E402
from temoto_core.processes import ProcessGroupLauncher  # noqa: E402
from temoto_core.master_reach import MasterReach  # noqa: E402
from temoto_core.wait import wait_for  # noqa: E402

THROTTLE = '/usr/lib/topic_tools/throttle'
NODES = 20
CHECKS = 300
RESTARTS = 5
FINDS = 50
PROBES = 300


def ms(values, p=50):
    return pct(values, p) * 1e3


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main() -> int:
    # a fixed port: the restarted master must be found where the old one was, as a rebooted robot's is
    master = RosMaster(tempfile.mkdtemp(prefix='bench_master_check_'), port=free_port()).start()
    master.point_this_process()
    procs = ProcessGroupLauncher(master.env, master.workdir)
    try:
        throttles = [procs.command([THROTTLE, 'messages', '/bench/in_%d' % i, '1', '/bench/out_%d' % i],
                                   'throttle_%d' % i) for i in range(NODES)]
        rospy.init_node('bench_master_check', disable_signals=True)
        pids = [p.pid for p in throttles]
        found = wait_for(lambda: (lambda nodes: nodes if len(nodes) == NODES else None)(
            master_rejoin.nodes_of_processes(pids)), 30, 'the %d throttles to register' % NODES)
        # their own periodic checks never come (the period is long): the bench runs each check itself
        bare = master_rejoin.MasterRejoin(period=1e6).start()
        speaking = master_rejoin.MasterRejoin(period=1e6).start()
        for node in found:
            speaking.adopt(node)

        quiet_bare, quiet_speaking = [], []
        for _ in range(CHECKS):
            quiet_bare.append(timed(bare.check))
            quiet_speaking.append(timed(speaking.check))

        again_bare, again_speaking = [], []
        for _ in range(RESTARTS):
            master.stop()
            master.start()
            # the first pass after the restart registers everything; the clock is on that pass alone
            again_bare.append(timed(bare.check))
            again_speaking.append(timed(speaking.check))
            wait_for(lambda: len(master_rejoin.nodes_of_processes(pids)) == NODES, 30, 'every throttle back')

        finds = [timed(lambda: master_rejoin.nodes_of_processes([pids[i % NODES]])) for i in range(FINDS)]
        reach = MasterReach()
        probes = [timed(reach.probe) for _ in range(PROBES)]
    finally:
        rospy.signal_shutdown('bench over')
        procs.stop_all()
        master.stop()

    result = {
        'nodes': NODES,
        'check_quiet_ms': {'none': [ms(quiet_bare), ms(quiet_bare, 95)],
                           'adopted': [ms(quiet_speaking), ms(quiet_speaking, 95)]},
        'check_new_run_ms': {'none': [ms(again_bare), max(again_bare) * 1e3],
                             'adopted': [ms(again_speaking), max(again_speaking) * 1e3]},
        'find_nodes_ms': [ms(finds), ms(finds, 95)],
        'master_probe_ms': [ms(probes), ms(probes, 95)],
    }
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'master_check.json'), 'w') as f:
        json.dump(result, f, indent=1)
    added_p95 = ms(quiet_speaking, 95) - ms(quiet_bare, 95)
    print('| figure | no adopted node | %d adopted nodes | goal |' % NODES)
    print('| --- | --- | --- | --- |')
    print('| the check while all is well, median / p95 | %.2f / %.2f ms | %.2f / %.2f ms | +%.2f ms at p95 (goal: '
          '<= +1 ms) |' % (ms(quiet_bare), ms(quiet_bare, 95), ms(quiet_speaking), ms(quiet_speaking, 95), added_p95))
    print('| the pass after a master restart, median / max of %d | %.0f / %.0f ms | %.0f / %.0f ms | <= 1,000 ms |'
          % (RESTARTS, ms(again_bare), max(again_bare) * 1e3, ms(again_speaking), max(again_speaking) * 1e3))
    print('| finding one process\'s nodes by its ports, median / p95 | - | %.1f / %.1f ms | p95 <= 50 ms |'
          % (ms(finds), ms(finds, 95)))
    print('| the master probe before a new status channel, median / p95 | - | %.2f / %.2f ms | p95 <= 1 ms |'
          % (ms(probes), ms(probes, 95)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
