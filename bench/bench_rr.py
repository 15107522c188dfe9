#!/usr/bin/env python3
"""Resource Registrar benchmark, every figure measured side by side in one run.

1. Load through an A -> B -> C registrar chain (three processes, nested calls),
   entered through A's JSON control service, against a bare chain of three
   rospy services (bare_a -> bare_b -> bare_c) entered the same way and doing
   the same parsing, so that only the registrar's work differs. Goal: ratio <= 1.3
   against a bare chain on persistent connections, and <= 1.0 against the chain as
   plain rospy code writes it (a connection per call, rospy's default).
2. A shared-resource hit: client side (an equal call the client already holds:
   no service call) and server side (another client's equal request).
3. Status propagation latency A <- B <- C: C's owner sends FAILED, A's status
   callback runs. Goal: median <= 5 ms.
4. Load + unload latency with 10 versus 10,000 active resources in one
   registrar. Goal: ratio <= 1.5.
5. Status fan-out: one resource held by N consumer registrars; time from the
   owner's FAILED to the last consumer's callback.

Prints a markdown table and writes bench/results/rr.json.
"""
import argparse
import json
import os
import statistics
import sys
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, 'tests'))

from common import loopback_master  # noqa: E402


def median_ms(values):
    return statistics.median(values) * 1e3


def timed(fn, n):
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--n', type=int, default=200, help='samples per latency figure')
    ap.add_argument('--active', type=int, default=10000, help='active resources for the scaling figure')
    ap.add_argument('--fanout', type=int, default=1000, help='consumers for the fan-out figure')
    args = ap.parse_args(argv)

    master, procs = loopback_master('bench_rr_')
    try:
        return run(args, procs)
    finally:
        procs.stop_all()
        master.stop()


def run(args, procs):
    import rospy
    from rr_helpers import RegistrarNode
    from temoto_core.rr import ResourceRegistrar
    from temoto_core.srv import LoadTestResource
    from temoto_test_nodes.srv import Control
    Req = LoadTestResource._request_class
    rospy.init_node('bench_rr', disable_signals=True)

    print('bench_rr: starting 3 registrar processes and a bare chain...', flush=True)
    a, b, c = (RegistrarNode(procs, n) for n in ('rr_a', 'rr_b', 'rr_c'))
    procs.node('temoto_test_nodes', 'bare_chain_node', name='bare_c')
    procs.node('temoto_test_nodes', 'bare_chain_node', name='bare_b', params={'next': '/bare_c/work'})
    procs.node('temoto_test_nodes', 'bare_chain_node', name='bare_a', params={'next': '/bare_b/work'})
    # the same chain as plain rospy code writes it: a connection per call (rospy's default)
    procs.node('temoto_test_nodes', 'bare_chain_node', name='plain_c')
    procs.node('temoto_test_nodes', 'bare_chain_node', name='plain_b',
               params={'next': '/plain_c/work', 'persistent': False})
    procs.node('temoto_test_nodes', 'bare_chain_node', name='plain_a',
               params={'next': '/plain_b/work', 'persistent': False})
    rospy.wait_for_service('/bare_a/control', 20)
    rospy.wait_for_service('/plain_a/control', 20)
    rows = []

    # 1. chain load vs bare chain (both entered through a persistent service call into A)
    ctl = rospy.ServiceProxy('/rr_a/control', Control, persistent=True)
    bare = rospy.ServiceProxy('/bare_a/control', Control, persistent=True)
    plain = rospy.ServiceProxy('/plain_a/control', Control, persistent=True)
    counter = iter(range(10 ** 9))
    ids = []

    def chain_load():
        name = 'r%d' % next(counter)
        out = json.loads(ctl(json.dumps({'op': 'call', 'rr': 'rr_b', 'name': name,
                                         'params': [['nested', 'rr_c/load_test/' + name]]})).result)
        ids.append(out['id'])

    def bare_load():
        name = 'b%d' % next(counter)
        json.loads(bare(json.dumps({'op': 'call', 'rr': 'rr_b', 'name': name,
                                    'params': [['nested', 'rr_c/load_test/' + name]]})).result)

    def plain_load():
        name = 'n%d' % next(counter)
        json.loads(plain(json.dumps({'op': 'call', 'rr': 'rr_b', 'name': name,
                                     'params': [['nested', 'rr_c/load_test/' + name]]})).result)

    for _ in range(20):                      # warm every path
        chain_load()
        bare_load()
        plain_load()
    rr_times, bare_times, plain_times = [], [], []
    for i in range(args.n):                  # interleaved, so noise hits all alike
        rr_times += timed(chain_load, 1)
        bare_times += timed(bare_load, 1)
        plain_times += timed(plain_load, 1)
    for rid in ids:
        ctl(json.dumps({'op': 'unload', 'id': rid}))
    ratio = median_ms(rr_times) / median_ms(bare_times)
    rows.append(('load through A->B->C (3 processes)', '%.2f ms' % median_ms(rr_times), ''))
    rows.append(('bare chain of 3 service calls, persistent connections', '%.2f ms' % median_ms(bare_times), ''))
    rows.append(('bare chain of 3 plain rospy calls (a connection per call)', '%.2f ms' % median_ms(plain_times),
                 ''))
    rows.append(('ratio registrar / bare persistent', '%.2f' % ratio, '<= 1.3'))
    rows.append(('ratio registrar / plain rospy', '%.2f' % (median_ms(rr_times) / median_ms(plain_times)), '<= 1.0'))
    print('bench_rr: chain done', flush=True)

    # 2. shared hits, from an in-process registrar
    mine = ResourceRegistrar('bench_client')
    other = ResourceRegistrar('bench_other')
    held = mine.call('rr_c', 'load_test', Req(name='shared'))
    hit_ids = []
    client_hits = timed(lambda: hit_ids.append(mine.call('rr_c', 'load_test', Req(name='shared')).trr.resource_id),
                        args.n)
    for rid in hit_ids:
        mine.unload(rid)
    server_hits = []
    for _ in range(args.n):
        t0 = time.perf_counter()
        res = other.call('rr_c', 'load_test', Req(name='shared'))
        server_hits.append(time.perf_counter() - t0)
        other.unload(res.trr.resource_id)
    fresh = []
    for i in range(args.n):
        t0 = time.perf_counter()
        res = other.call('rr_c', 'load_test', Req(name='fresh%d' % i))
        fresh.append(time.perf_counter() - t0)
        other.unload(res.trr.resource_id)
    mine.unload(held.trr.resource_id)
    rows.append(('shared hit, client side (no service call)', '%.3f ms' % median_ms(client_hits), ''))
    rows.append(('shared hit, server side (cached response)', '%.2f ms' % median_ms(server_hits), ''))
    rows.append(('fresh load, one hop (for comparison)', '%.2f ms' % median_ms(fresh), ''))

    # 3. status propagation A <- B <- C
    lat = []
    for i in range(min(args.n, 100)):
        name = 'p%d' % i
        res = a.call('rr_b', name, [('nested', 'rr_c/load_test/' + name)])
        before = len(a.events())
        sent = c.fail(name)['sent']
        deadline = time.monotonic() + 10
        while len(a.events()) <= before and time.monotonic() < deadline:
            time.sleep(0.001)
        ev = a.events()[-1]
        lat.append(ev['received'] - sent)
        a.unload(res['id'])
    rows.append(('status propagation C -> B -> A', '%.2f ms (p90 %.2f)' % (median_ms(lat),
                 sorted(lat)[int(0.9 * (len(lat) - 1))] * 1e3), '<= 5 ms median'))
    print('bench_rr: propagation done', flush=True)

    # 4. scaling with active resources in one registrar (rr_c)
    def load_unload():
        res = other.call('rr_c', 'load_test', Req(name='probe'))
        other.unload(res.trr.resource_id)

    bulk = [mine.call('rr_c', 'load_test', Req(name='bulk%d' % i)).trr.resource_id for i in range(10)]
    small = timed(load_unload, args.n)
    print('bench_rr: loading %d active resources...' % args.active, flush=True)
    bulk += [mine.call('rr_c', 'load_test', Req(name='bulk%d' % i)).trr.resource_id for i in range(10, args.active)]
    large = []
    for _ in range(args.n):                  # alternate is not possible here; repeat the small set after
        large += timed(load_unload, 1)
    for rid in bulk[10:]:
        mine.unload(rid)
    small2 = timed(load_unload, args.n)
    for rid in bulk[:10]:
        mine.unload(rid)
    small_all = small + small2
    scale = median_ms(large) / median_ms(small_all)
    rows.append(('load+unload, 10 active', '%.2f ms' % median_ms(small_all), ''))
    rows.append(('load+unload, %d active' % args.active, '%.2f ms' % median_ms(large), ''))
    rows.append(('ratio %d / 10 active' % args.active, '%.2f' % scale, '<= 1.5'))
    print('bench_rr: scaling done', flush=True)

    # 5. fan-out to N consumer registrars (in this process)
    got = []
    done = threading.Event()
    lock = threading.Lock()

    def on_status(_ev):
        with lock:
            got.append(time.time())
            if len(got) == args.fanout:
                done.set()

    # A thousand registrars in one process is a stress of its own: each watches rr_c from its own thread, and
    # with rr_c serving ten thousand resources and a thousand new status channels, one side or the other was
    # starved past the 3 s bound for an owner that takes connections but does not answer (docs/failures.md):
    # rr_c was then called wedged, falsely. These consumers give it 30 s; the figure is the fan-out's.
    rospy.set_param('~owner_busy_bound', 30.0)
    consumers = [ResourceRegistrar('fan%d' % i) for i in range(args.fanout)]
    rospy.delete_param('~owner_busy_bound')
    # a thousand new consumers in one process: a first call waits for its status channel, under load for
    # longer than the 1 s default deadline (a stress figure, not a latency one)
    held = [rr.call('rr_c', 'load_test', Req(name='fanned'), status_cb=on_status, deadline=30.0)
            for rr in consumers]
    sent = c.fail('fanned')['sent']
    done.wait(60)
    fan = (max(got) - sent) if got else float('nan')
    rows.append(('fan-out of one FAILED to %d consumers (to the last)' % args.fanout,
                 '%.0f ms (%d delivered)' % (fan * 1e3, len(got)), ''))
    for rr, res in zip(consumers, held):
        rr.unload(res.trr.resource_id)
        rr.shutdown()

    print('\n| Resource Registrar | measured | goal |\n| --- | --- | --- |')
    for name, value, goal in rows:
        print('| %s | %s | %s |' % (name, value, goal or '-'))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'rr.json'), 'w') as f:
        json.dump({'rows': rows, 'chain_ratio': ratio, 'scale_ratio': scale,
                   'propagation_median_ms': median_ms(lat)}, f, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
