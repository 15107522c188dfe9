#!/usr/bin/env python3
"""Sensor Manager benchmark: failure latency two hops up, and load time until first data.

A client registrar in this process holds a sensor from the Sensor Manager, which
holds the driver process from the ER Manager: client -> start_sensor -> load_process.

1. Crash: the D435's cable is pulled in crash mode (`temoto sim unplug d435 --mode crash`);
   measured from the service call that pulls it to the FAILED status callback at the client
   (the ER Manager sees the exit, the Sensor Manager's registrar forwards it). The D435 runs
   from a launch file, so the ER Manager's launch runner sits in between; the same chain with a
   plain node driver (a fake sensor told to exit) shows what the managers themselves add.
2. Stall: the cable is pulled in stall mode (the driver stays alive, silent); measured the same
   way. The stall comes right after the load, while the stall detector still learns the topic's rhythm, so it
   waits the catalogue's silence limit (config/vaultbot.yaml), and the figure of interest is the latency
   beyond that limit (the learnt limit is bench_stall.py's).
3. Load until first data: start_sensor until its response, which arrives only once the first
   message is on every output topic (D435 cloud; SICK scan; a trivial fake driver as the floor).

Prints a markdown table and writes bench/results/sensor.json.
Usage: python bench/bench_sensor.py [--failures N] [--loads N]
"""
import argparse
import json
import os
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from common import loopback_master, pct  # noqa: E402

from temoto_testing import FirstFailure  # noqa: E402

CRASH_GOAL_MS = 100.0         # exit seen by the ER Manager (pidfd) and forwarded one registrar up
STALL_EXTRA_GOAL_MS = 100.0   # beyond the silence limit: one stall detector wake-up plus the status hop
LOAD_GOAL_S = 5.0             # D435 (pybullet scene load + first rendered cloud) on a 2-core machine


def summary(values, scale=1e3):
    return {'n': len(values), 'median': statistics.median(values) * scale, 'p90': pct(values, 90) * scale,
            'min': min(values) * scale, 'max': max(values) * scale}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--failures', type=int, default=5, help='unplugs per mode')
    ap.add_argument('--loads', type=int, default=4, help='loads per sensor')
    opts = ap.parse_args(argv)
    ros, launcher = loopback_master('bench_sensor_')
    results = {}
    try:
        import rospy
        from diagnostic_msgs.msg import KeyValue
        from temoto_core.rr import ResourceRegistrar
        from temoto_sensor_manager.srv import LoadSensor
        from temoto_testing import sensor_manager as t
        rospy.init_node('bench_sensor', disable_signals=True)
        print('starting the simulation and the managers ...', flush=True)
        t.start_robot(launcher, launcher.workdir)
        rr = ResourceRegistrar('bench_sensor_client')

        def request(sensor_type, topics, executable=''):
            return LoadSensor._request_class(sensor_type=sensor_type, executable=executable,
                                             output_topics=[KeyValue(k, '') for k in topics])

        def failure_latency(mode, topics):
            out = []
            for i in range(opts.failures):
                failed = FirstFailure()
                resp = rr.call('temoto_sensor_manager', 'start_sensor',
                               request('depth camera', topics, 'd435_driver'), status_cb=failed)
                t0 = time.monotonic()
                t.set_cable('d435', 'unplugged', mode)
                out.append(failed.wait(10.0, 'FAILED after a %s unplug' % mode) - t0)
                rr.unload(resp.trr.resource_id)
                t.set_cable('d435', 'plugged')
                print('  %s %d/%d: %.1f ms' % (mode, i + 1, opts.failures, out[-1] * 1e3), flush=True)
            return out

        crash = failure_latency('crash', ['camera_data'])

        # the same chain with a plain node driver (no launch file): what the managers themselves add
        cables = t.FakeCables()
        node_crash = []
        for i in range(opts.failures):
            failed = FirstFailure()
            resp = rr.call('temoto_sensor_manager', 'start_sensor', request('fake lidar', ['lidar_data']),
                           status_cb=failed)
            t0 = cables.send('crash', resp.sensor_name[len('fake_'):])
            node_crash.append(failed.wait(10.0, 'FAILED after a fake driver crash') - t0)
            rr.unload(resp.trr.resource_id)
            t.managers_idle(timeout=20)
            print('  node crash %d/%d: %.1f ms' % (i + 1, opts.failures, node_crash[-1] * 1e3), flush=True)
        stall = failure_latency('stall', ['camera_info'])
        limit = t.catalogue()['realsense_d435']['output_topics']['camera_info']['stall_limit']

        loads = {}
        for label, sensor_type, topics, exe in (('D435 cloud', 'depth camera', ['camera_data'], 'd435_driver'),
                                                ('SICK scan', 'lidar', ['lidar_data'], 'sick_driver'),
                                                ('fake driver (floor)', 'fake lidar', ['lidar_data'], '')):
            times = []
            for i in range(opts.loads):
                t0 = time.monotonic()
                resp = rr.call('temoto_sensor_manager', 'start_sensor', request(sensor_type, topics, exe))
                times.append(time.monotonic() - t0)
                rr.unload(resp.trr.resource_id)
                t.managers_idle(timeout=20)
                print('  load %s %d/%d: %.2f s' % (label, i + 1, opts.loads, times[-1]), flush=True)
            loads[label] = times
        rr.shutdown()
    finally:
        launcher.stop_all()
        ros.stop()

    c, s, nc = summary(crash), summary(stall), summary(node_crash)
    s_extra = summary([x - limit for x in stall])
    results = {'crash_to_failed_ms': c, 'node_driver_crash_to_failed_ms': nc, 'stall_to_failed_ms': s,
               'stall_beyond_limit_ms': s_extra,
               'stall_limit_s': limit, 'load_until_first_data_s': {k: summary(v, 1.0) for k, v in loads.items()},
               'goals': {'crash_median_ms': CRASH_GOAL_MS, 'stall_beyond_limit_median_ms': STALL_EXTRA_GOAL_MS,
                         'd435_load_median_s': LOAD_GOAL_S},
               'machine': {'cpus': os.cpu_count()}, 'time': time.time()}
    print()
    print('| figure | value | goal |')
    print('| --- | --- | --- |')
    print('| D435 unplug (crash) to FAILED at a client two hops up (n=%d) | median %.1f ms, p90 %.1f ms, max %.1f ms '
          '| median <= %.0f ms |' % (c['n'], c['median'], c['p90'], c['max'], CRASH_GOAL_MS))
    print('| same chain, a plain node driver (fake_sensor) crashing (n=%d) | median %.1f ms, p90 %.1f ms | reference '
          '(what the managers add) |' % (nc['n'], nc['median'], nc['p90']))
    print('| D435 unplug (stall) to FAILED at a client two hops up (n=%d), silence limit %.1f s | median %.1f ms, '
          'p90 %.1f ms | limit + %.0f ms |' % (s['n'], limit, s['median'], s['p90'], STALL_EXTRA_GOAL_MS))
    print('| ... of which beyond the silence limit | median %.1f ms, p90 %.1f ms, max %.1f ms | median <= %.0f ms |'
          % (s_extra['median'], s_extra['p90'], s_extra['max'], STALL_EXTRA_GOAL_MS))
    for label, v in results['load_until_first_data_s'].items():
        goal = 'median <= %.0f s' % LOAD_GOAL_S if label.startswith('D435') else 'reference'
        print('| load until first data, %s (n=%d) | median %.2f s, p90 %.2f s | %s |'
              % (label, v['n'], v['median'], v['p90'], goal))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'sensor.json'), 'w') as f:
        json.dump(results, f, indent=2, sort_keys=True)
    ok = (c['median'] <= CRASH_GOAL_MS and s_extra['median'] <= STALL_EXTRA_GOAL_MS and
          results['load_until_first_data_s']['D435 cloud']['median'] <= LOAD_GOAL_S)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
