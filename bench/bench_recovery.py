#!/usr/bin/env python3
"""Kill the ER Manager, respawn it, and time until its registry is the one before the kill.

A real roscore, a real ER Manager with a journal, a consumer registrar in this process holding
``--resources`` driver processes. Each round: wait a seeded random time, SIGKILL the manager, start it
again at once (as roslaunch's respawn does), and poll ``/<ns>/temoto_er_manager/registry`` until it
answers with the registry recorded before the kill. Every round also checks, against reality:

- lost: a resource of the registry before that is missing after, or not active;
- duplicated: a driver pid that changed, or more driver processes than resources;
- orphaned: a driver process running that no resource of the registry has.

Goal: <= 1.0 s at p95 over at least 200 kills, with 0 lost, 0 orphaned, 0 duplicated.
Prints a markdown table and writes bench/results/recovery.json.
"""
import argparse
import json
import os
import random
import signal
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from temoto_core.process_group import start_ticks  # noqa: E402
from temoto_core.testing import ProcessGroupLauncher, RosMaster  # noqa: E402

MGR = 'temoto_er_manager'


def ms(values, q):
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] * 1e3


def registry_now(proxy_factory):
    """The manager's registry as comparable JSON, or None while it does not answer."""
    try:
        raw = json.loads(proxy_factory()().json)
    except Exception:            # not up yet: a dead URI, a refused connection, a service not advertised
        return None
    raw.pop('node', None)
    return json.dumps(raw, sort_keys=True)


def driver_pids(text):
    return sorted(q['details']['pid'] for q in json.loads(text)['server_queries'])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--kills', type=int, default=200)
    ap.add_argument('--resources', type=int, default=3, help='driver processes held across the kills')
    ap.add_argument('--seed', type=int, default=14)
    args = ap.parse_args(argv)
    rng = random.Random(args.seed)
    work = tempfile.mkdtemp(prefix='bench_recovery_')
    master = RosMaster(work).start()
    try:
        master.point_this_process()
        import rospy
        from temoto_core.rr import ResourceRegistrar
        from temoto_core.srv import GetRegistry
        from temoto_er_manager.srv import LoadProcess
        rospy.init_node('bench_recovery', disable_signals=True)
        launcher = ProcessGroupLauncher(master.env, work)
        params = {'journal': os.path.join(work, 'er.sqlite'), 'log_dir': os.path.join(work, 'logs'),
                  'registration_timeout': 15.0, 'sigint_grace': 2.0, 'sigterm_grace': 1.0}
        manager = launcher.node(MGR, MGR, name=MGR, params=params)
        rospy.wait_for_service('/temoto/%s/load_process' % MGR, timeout=30)
        consumer = ResourceRegistrar('bench_recovery_consumer', namespace='temoto')
        held = []
        for i in range(args.resources):
            req = LoadProcess._request_class(action='ros_execute', package_name='temoto_er_manager',
                                             executable='er_test_node', args='__name:=bench_driver_%d' % i)
            held.append(consumer.call(MGR, 'load_process', req))
        service = '/temoto/%s/registry' % MGR
        factory = lambda: rospy.ServiceProxy(service, GetRegistry)      # noqa: E731
        marker = ('ROS_MASTER_URI=' + master.uri).encode()       # drivers of this run, not of another
        before = registry_now(factory)
        pids = driver_pids(before)
        starts = {pid: start_ticks(pid) for pid in pids}
        times, lost, duplicated, orphaned, failures = [], 0, 0, 0, []
        for k in range(args.kills):
            time.sleep(rng.uniform(0.0, 0.3))               # a seeded point in the manager's life
            os.kill(manager.pid, signal.SIGKILL)
            t0 = time.monotonic()
            manager.proc.wait()
            manager = launcher.node(MGR, MGR, name=MGR, params=params, wait=False)
            after, deadline = None, t0 + 30.0
            while time.monotonic() < deadline:
                after = registry_now(factory)
                if after == before:
                    break
                time.sleep(0.005)
            elapsed = time.monotonic() - t0
            if after != before:
                failures.append('kill %d: registry not recovered within 30 s' % k)
                now = json.loads(after) if after else {'server_queries': []}
                lost += len(pids) - sum(1 for q in now['server_queries'] if q['state'] == 'active')
                break
            times.append(elapsed)
            alive = [pid for pid in pids if start_ticks(pid) == starts[pid]]
            lost += len(pids) - len(alive)
            duplicated += len(driver_pids(after)) - len(pids) + sum(1 for p in driver_pids(after) if p not in pids)
            strays = [p for p in os.listdir('/proc') if p.isdigit() and int(p) not in pids and
                      b'er_test_node' in _read(p, 'cmdline') and marker in _read(p, 'environ').split(b'\0')
                      and start_ticks(int(p)) is not None]
            orphaned += len(strays)
            if (k + 1) % 20 == 0:
                print('  %d kills: p95 so far %.0f ms' % (k + 1, ms(times, 0.95)), file=sys.stderr)
        for res in held:
            consumer.unload(res.trr.resource_id)
        consumer.shutdown()
        launcher.stop_all()
    finally:
        master.stop()
    result = {'kills': len(times), 'resources': args.resources, 'seed': args.seed,
              'median_ms': ms(times, 0.5), 'p95_ms': ms(times, 0.95), 'max_ms': max(times) * 1e3,
              'lost': lost, 'duplicated': duplicated, 'orphaned': orphaned, 'failures': failures}
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'recovery.json'), 'w') as f:
        json.dump(result, f, indent=1)
    print('| figure | value | goal |\n|---|---|---|')
    print('| ER Manager SIGKILLed and respawned: registry equal to before, median / p95 / max (%d kills, %d '
          'drivers held) | %.0f / %.0f / %.0f ms | p95 <= 1000 ms |'
          % (len(times), args.resources, result['median_ms'], result['p95_ms'], result['max_ms']))
    print('| lost / duplicated / orphaned resources | %d / %d / %d | 0 / 0 / 0 |' % (lost, duplicated, orphaned))
    for failure in failures:
        print('FAILED: ' + failure)
    return 1 if failures else 0


def _read(pid, what):
    try:
        with open('/proc/%s/%s' % (pid, what), 'rb') as f:
            return f.read()
    except OSError:
        return b''


if __name__ == '__main__':
    sys.exit(main())
