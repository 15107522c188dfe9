#!/usr/bin/env python3
"""The cost of the registrar's journal, measured side by side in one run.

1. One registry change written to the journal (SQLite, WAL, synchronous=NORMAL)
   with 10,000 active resources recorded: a consumer attached, then detached,
   each its own transaction. Goal: <= 0.5 ms per change at p95.
2. Load through an A -> B -> C registrar chain (three processes), with every
   registrar journaling against the same chain without journals and a bare chain
   of three rospy services, interleaved. Goal: the chain ratio (registrar / bare)
   no worse with the journal on than off (1.34 to 1.49 across runs before).

Prints a markdown table and writes bench/results/journal.json.
"""
import argparse
import json
import os
import statistics
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, 'tests'))

from temoto_core.rr.journal import Journal, JournaledConsumer  # noqa: E402
from temoto_testing import ProcessGroupLauncher, RosMaster  # noqa: E402


def ms(values, q=0.5):
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] * 1e3


def journal_changes(active: int, n: int, workdir: str):
    journal = Journal(os.path.join(workdir, 'bench.sqlite3'), run_id='bench')
    payload = b'r' * 300                  # about a LoadSensor request with its topics
    for i in range(1, active + 1):
        journal.serve(i, 'start_sensor', 'pkg/Req', payload, payload, active + i,
                      JournaledConsumer(active + i, '/temoto/a/status', '/a', 'temoto', 'http://h:1/', 1))
    times = []
    for k in range(n):
        ext = 10 * active + k
        consumer = JournaledConsumer(ext, '/temoto/b/status', '/b', 'temoto', 'http://h:2/', 1)
        t0 = time.perf_counter()
        journal.attach('start_sensor', 1 + k % active, consumer)
        t1 = time.perf_counter()
        journal.detach('start_sensor', ext)
        t2 = time.perf_counter()
        times += [t1 - t0, t2 - t1]
    journal.close()
    return times


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--n', type=int, default=300, help='samples per figure')
    ap.add_argument('--active', type=int, default=10000, help='active resources recorded in the journal')
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as workdir:
        print('bench_journal: writing %d resources, then timing changes...' % args.active, flush=True)
        changes = journal_changes(args.active, args.n, workdir)
        rows.append(('one registry change written, %d active (median)' % args.active, '%.3f ms' % ms(changes), ''))
        rows.append(('one registry change written, %d active (p95)' % args.active, '%.3f ms' % ms(changes, 0.95),
                     '<= 0.5 ms'))
        master = RosMaster().start()
        master.point_this_process()
        procs = ProcessGroupLauncher(master.env, master.workdir)
        try:
            ratios = chains(args, procs, workdir)
        finally:
            procs.stop_all()
            master.stop()
    plain, journaled, bare = ratios
    rows.append(('load through A->B->C, no journal', '%.2f ms' % plain, ''))
    rows.append(('load through A->B->C, every registrar journaling', '%.2f ms' % journaled, ''))
    rows.append(('bare chain of 3 service calls', '%.2f ms' % bare, ''))
    rows.append(('chain ratio registrar / bare, journal off', '%.2f' % (plain / bare), ''))
    rows.append(('chain ratio registrar / bare, journal on', '%.2f' % (journaled / bare), 'no worse than off'))
    print('\n| Journal | measured | goal |\n| --- | --- | --- |')
    for name, value, goal in rows:
        print('| %s | %s | %s |' % (name, value, goal or '-'))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'journal.json'), 'w') as f:
        json.dump({'rows': rows}, f, indent=2)
    return 0


def chains(args, procs, workdir):
    import rospy
    from rr_helpers import RegistrarNode
    from temoto_test_nodes.srv import Control
    rospy.init_node('bench_journal', disable_signals=True)
    print('bench_journal: starting two registrar chains and a bare chain...', flush=True)
    for n in ('rr_a', 'rr_b', 'rr_c'):
        RegistrarNode(procs, n)
    for n in ('rr_ja', 'rr_jb', 'rr_jc'):
        RegistrarNode(procs, n, journal=os.path.join(workdir, n + '.sqlite3'))
    procs.node('temoto_test_nodes', 'bare_chain_node', name='bare_c')
    procs.node('temoto_test_nodes', 'bare_chain_node', name='bare_b', params={'next': '/bare_c/work'})
    procs.node('temoto_test_nodes', 'bare_chain_node', name='bare_a', params={'next': '/bare_b/work'})
    rospy.wait_for_service('/bare_a/control', 20)
    entries = {'plain': ('/rr_a/control', 'rr_b', 'rr_c'), 'journaled': ('/rr_ja/control', 'rr_jb', 'rr_jc'),
               'bare': ('/bare_a/control', 'rr_b', 'rr_c')}
    proxies = {k: rospy.ServiceProxy(v[0], Control, persistent=True) for k, v in entries.items()}
    counter = iter(range(10 ** 9))
    held = {'plain': [], 'journaled': []}
    times = {k: [] for k in entries}

    def load(kind):
        _, mid, bottom = entries[kind]
        name = 'r%d' % next(counter)
        t0 = time.perf_counter()
        out = json.loads(proxies[kind](json.dumps({'op': 'call', 'rr': mid, 'name': name,
                                                   'params': [['nested', '%s/load_test/%s' % (bottom, name)]]})).result)
        elapsed = time.perf_counter() - t0
        if kind in held:
            held[kind].append(out['id'])
        return elapsed

    for _ in range(20):
        for kind in entries:
            load(kind)
    for _ in range(args.n):                   # interleaved, so noise hits all three alike
        for kind in entries:
            times[kind].append(load(kind))
    for kind, ids in held.items():
        for rid in ids:
            proxies[kind](json.dumps({'op': 'unload', 'id': rid}))
    return tuple(statistics.median(times[k]) * 1e3 for k in ('plain', 'journaled', 'bare'))


if __name__ == '__main__':
    sys.exit(main())
