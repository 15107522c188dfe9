#!/usr/bin/env python3
"""Node stop benchmark: SIGINT to process exit, rospy's own signal handling against temoto_core.node.

A supervisor's unload (ER Manager) and every test teardown wait for this. The
same trivial node (temoto_er_manager/er_minimal_node, registered and spinning)
is started with each lifecycle in turn, so machine load hits both alike, and
stopped with SIGINT to its process group; measured from the signal to the exit
seen by waitid. temoto_core.node moves the shutdown out of the signal handler
(which could deadlock, see temoto_core/node.py); this shows what that costs.
Both run rospy's own shutdown, whose waits on its internal threads (which wake
every 0.5 s) make most of the time; the signal is sent as soon as the node is
registered, so a stop during start-up counts too.

Prints a markdown table and writes bench/results/node_stop.json.
Usage: python bench/bench_node_stop.py [--stops N]
"""
import argparse
import json
import os
import signal
import statistics
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from temoto_core.process_group import exit_status  # noqa: E402
from temoto_testing import ProcessGroupLauncher, RosMaster  # noqa: E402

MODES = ('rospy', 'temoto')
HANG = 10.0     # s: a stop slower than this counts as hung (and is ended by stop())


def stop_once(launcher, mode, index):
    proc = launcher.node('temoto_er_manager', 'er_minimal_node', args=['_spin:=' + mode],
                         name='stop_%s_%d' % (mode, index))
    t0 = time.monotonic()
    os.killpg(proc.pid, signal.SIGINT)
    while exit_status(proc.proc) is None and time.monotonic() - t0 < HANG:
        time.sleep(0.002)
    took = time.monotonic() - t0
    rc = proc.stop()
    return took, rc


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--stops', type=int, default=15)
    opts = p.parse_args()
    work = tempfile.mkdtemp(prefix='bench_node_stop_')
    ros = RosMaster(work).start()
    launcher = ProcessGroupLauncher(ros.env, work)
    times = {m: [] for m in MODES}
    codes = {m: [] for m in MODES}
    try:
        for i in range(opts.stops):
            for mode in MODES:
                took, rc = stop_once(launcher, mode, i)
                times[mode].append(took)
                codes[mode].append(rc)
            print('  stop %2d/%d: rospy %.0f ms, temoto %.0f ms' % (i + 1, opts.stops, times['rospy'][-1] * 1e3,
                                                                   times['temoto'][-1] * 1e3), flush=True)
    finally:
        launcher.stop_all()
        ros.stop()
    med = {m: statistics.median(times[m]) for m in MODES}
    results = {m: {'n': len(times[m]), 'median_ms': med[m] * 1e3, 'max_ms': max(times[m]) * 1e3,
                   'unclean_exits': sum(1 for c in codes[m] if c != 0)} for m in MODES}
    results['ratio_temoto_over_rospy'] = med['temoto'] / med['rospy']
    results['time'] = time.time()
    print()
    print('| SIGINT to exit of a spinning node (n=%d each, alternating) | rospy init_node/spin | temoto_core.node | '
          'goal |' % opts.stops)
    print('| --- | --- | --- | --- |')
    print('| median (max) | %.0f ms (%.0f ms) | %.0f ms (%.0f ms) | no slower: ratio %.2f (<= 1.05) |'
          % (med['rospy'] * 1e3, max(times['rospy']) * 1e3, med['temoto'] * 1e3, max(times['temoto']) * 1e3,
             results['ratio_temoto_over_rospy']))
    print('| exits other than 0 | %d | %d | 0 |' % (results['rospy']['unclean_exits'],
                                                 results['temoto']['unclean_exits']))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'node_stop.json'), 'w') as f:
        json.dump(results, f, indent=2, sort_keys=True)
    return 0 if results['temoto']['unclean_exits'] == 0 and results['ratio_temoto_over_rospy'] <= 1.05 else 1


if __name__ == '__main__':
    sys.exit(main())
