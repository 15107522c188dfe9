#!/usr/bin/env python3
"""The robot and the operator's station on two hosts, and the link between them failing.

The hosts are two network namespaces joined by a veth pair (temoto_core/hosts.py):
the robot runs the master and owner C, the operator runs consumer A, and a second
consumer L runs on the robot beside C. Every node is driven through a Unix socket.

1. A remote load (A -> C across the hosts) against a local one (L -> C), interleaved.
   Goal: ratio <= 1.5.
2. Status propagation across the hosts: C sends FAILED, A's callback runs.
   Goal: median <= 5 ms.
3. Partition detection: A holds a resource from C, the link goes down; time until
   A's callback hears FAILED. Goal: <= 1 s, every cycle.
4. Calls during a partition: none outlives its deadline (1 s).
5. Seeded partition and heal cycles (a cut while idle or during a load, then the
   heal): after each, every load at C released once, both registries empty, and
   no process more than at the start. Goal: 0 double ownership, 0 leaks.
6. Host loss: every process of the robot host killed (the master too); time until
   A hears FAILED. Goal: <= 1 s.

Needs root (network namespaces). Prints a markdown table and writes bench/results/hosts.json.
"""
import argparse
import json
import os
import random
import statistics
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, 'tests'))
from common import pct  # noqa: E402

from temoto_core import hosts as hosts_mod  # noqa: E402
from temoto_core.wait import wait_for  # noqa: E402
from rr_helpers import RegistrarNode, registry_empty  # noqa: E402


def median_ms(values):
    return statistics.median(values) * 1e3


def p95_ms(values):
    return pct(values, 95) * 1e3


class Station:
    """The master and the three nodes, started on the two hosts."""

    def __init__(self, hosts, workdir: str) -> None:
        self.hosts = hosts
        self.workdir = workdir
        self.master = hosts.master(os.path.join(workdir, 'master'))
        os.makedirs(self.master.workdir, exist_ok=True)
        self.master.start()
        self.robot = hosts.launcher(hosts.robot, self.master, workdir)
        self.operator = hosts.launcher(hosts.operator, self.master, workdir)
        self.c = RegistrarNode(self.robot, 'rr_c', control_socket=os.path.join(workdir, 'c.sock'))
        self.l = RegistrarNode(self.robot, 'rr_l', control_socket=os.path.join(workdir, 'l.sock'))
        self.a = RegistrarNode(self.operator, 'rr_a', control_socket=os.path.join(workdir, 'a.sock'))

    def stop(self) -> None:
        self.hosts.link(True)
        self.operator.stop_all()
        self.robot.stop_all()
        self.master.stop()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--n', type=int, default=200, help='samples per latency figure')
    ap.add_argument('--cycles', type=int, default=100, help='seeded partition and heal cycles')
    ap.add_argument('--detections', type=int, default=10, help='partitions timed for detection')
    ap.add_argument('--losses', type=int, default=5, help='robot hosts killed')
    ap.add_argument('--seed', type=int, default=15)
    args = ap.parse_args(argv)
    why = hosts_mod.unavailable()
    if why:
        print('bench_hosts: %s' % why, file=sys.stderr)
        return 1
    hosts = hosts_mod.TwoHosts('bh%d' % (os.getpid() % 10000)).up()
    workdir = tempfile.mkdtemp(prefix='bench_hosts_')
    try:
        rows = run(args, hosts, workdir)
    finally:
        hosts.down()
    print('| figure | value | goal |')
    print('|---|---|---|')
    for row in rows:
        print('| %s | %s | %s |' % row)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'hosts.json'), 'w') as f:
        json.dump(rows, f, indent=1)
    return 0


def run(args, hosts, workdir):
    rows = []
    station = Station(hosts, os.path.join(workdir, 'main'))
    a, c, local = station.a, station.c, station.l
    try:
        # 1. remote against local loads, interleaved
        print('bench_hosts: loads...', flush=True)
        remote_t, local_t = [], []
        for i in range(args.n + 10):
            for node, out in ((a, remote_t), (local, local_t)):
                t0 = time.perf_counter()
                res = node.call('rr_c', 'r%d' % i)
                took = time.perf_counter() - t0
                node.unload(res['id'])
                if i >= 10:              # the first ones warm the connections
                    out.append(took)
        rows.append(('load, operator -> robot (across the hosts)', '%.2f ms (p95 %.2f)'
                     % (median_ms(remote_t), p95_ms(remote_t)), ''))
        rows.append(('load, robot -> robot (same host)', '%.2f ms (p95 %.2f)'
                     % (median_ms(local_t), p95_ms(local_t)), ''))
        rows.append(('ratio remote / local load', '%.2f' % (median_ms(remote_t) / median_ms(local_t)), '<= 1.5'))

        # 2. status propagation across the hosts
        print('bench_hosts: status propagation...', flush=True)
        lat = []
        for i in range(min(args.n, 100)):
            name = 's%d' % i
            res = a.call('rr_c', name)
            before = len(a.events())
            sent = c.fail(name)['sent']
            events = wait_for(lambda: len(a.events()) > before and a.events(), 10, 'the status at A')
            lat.append(events[-1]['received'] - sent)
            a.unload(res['id'])
        rows.append(('status propagation robot -> operator', '%.2f ms (p95 %.2f)' % (median_ms(lat), p95_ms(lat)),
                     '<= 5 ms median'))

        # 3. partition detection, and 4. calls during a partition
        print('bench_hosts: partition detection...', flush=True)
        detect, call_over = [], []
        for i in range(args.detections):
            res = a.call('rr_c', 'd%d' % i)
            before = len(a.events())
            cut = time.time()
            hosts.link(False)
            events = wait_for(lambda: len(a.events()) > before and a.events(), 10, 'FAILED at A')
            detect.append(events[-1]['received'] - cut)
            t0 = time.monotonic()
            a.command(op='call', rr='rr_c', name='x%d' % i, deadline=1.0)
            call_over.append(time.monotonic() - t0)
            hosts.link(True)
            a.unload(res['id'])
            wait_for(lambda: c.counts()['unloads'] == c.counts()['loads'], 15, 'every load at C released')
        rows.append(('partition detected (link down -> FAILED at A)', 'median %.0f ms, max %.0f ms'
                     % (median_ms(detect), max(detect) * 1e3), '<= 1 s'))
        rows.append(('longest call during a partition (deadline 1 s)', '%.0f ms' % (max(call_over) * 1e3),
                     '<= 1000 ms'))

        # 5. seeded partition and heal cycles
        print('bench_hosts: %d partition and heal cycles...' % args.cycles, flush=True)
        rng = random.Random(args.seed)
        baseline = {h.name: len(hosts.pids(h)) for h in hosts.hosts}
        doubles = leaks = 0
        for i in range(args.cycles):
            kind = rng.choice(('idle', 'load'))
            if kind == 'idle':
                res = a.call('rr_c', 'k%d' % i)
                hosts.link(False)
                wait_for(lambda: any(e['id'] == res['id'] for e in a.events()), 10, 'FAILED at A')
                hosts.link(True)
                a.unload(res['id'])
            else:
                caller = threading.Thread(target=a.command, kwargs=dict(
                    op='call', rr='rr_c', name='k%d' % i, params=[['delay', '%.2f' % rng.uniform(0.2, 1.0)]]))
                caller.start()
                wait_for(lambda: c.counts()['loads'].get('k%d' % i), 10, 'the load at C')
                time.sleep(rng.uniform(0.0, 0.3))     # the cut lands anywhere in the load: a seeded fault time
                hosts.link(False)
                caller.join(15)
                hosts.link(True)
                a.command(op='release_all')     # an unload that cannot be sent yet is owed: checked below
            try:
                wait_for(lambda: registry_empty(a) and registry_empty(c), 15, 'empty registries')
                counts = c.counts()
                name = 'k%d' % i
                if counts['loads'].get(name, 0) > 1:          # loaded twice for one request
                    doubles += 1
                if counts['unloads'].get(name, 0) != counts['loads'].get(name, 0):
                    leaks += 1
            except TimeoutError:
                leaks += 1
            now = {h.name: len(hosts.pids(h)) for h in hosts.hosts}
            if now != baseline:
                leaks += 1
        rows.append(('seeded partition and heal cycles (seed %d)' % args.seed, '%d cycles: %d double ownership, '
                     '%d leaked' % (args.cycles, doubles, leaks), '0 and 0'))
    finally:
        station.stop()

    # 6. host loss
    print('bench_hosts: robot host losses...', flush=True)
    lost = []
    for i in range(args.losses):
        station = Station(hosts, os.path.join(workdir, 'loss%d' % i))
        try:
            res = station.a.call('rr_c', 'cam')
            killed = time.time()
            hosts.kill_all(hosts.robot)
            events = wait_for(lambda: station.a.events(), 10, 'FAILED at A')
            assert events[0]['id'] == res['id'], events
            lost.append(events[0]['received'] - killed)
        finally:
            station.stop()
    rows.append(('robot host lost -> FAILED at the operator', 'median %.0f ms, max %.0f ms'
                 % (median_ms(lost), max(lost) * 1e3), '<= 1 s'))
    return rows


if __name__ == '__main__':
    sys.exit(main())
