#!/usr/bin/env python3
"""Stall detection from each sensor's own rhythm: how fast a stall is caught, and how often a healthy
sensor is called stalled, with two CPU hogs loading the machine.

The simulated VaultBot's three sensors are held through the Sensor Manager at once (D435 cloud at 30 Hz,
SICK scan at 25 Hz, Hokuyo scan at 40 Hz), beside two busy-looping processes, for ``--minutes``: every
FAILED in that time is a false one. Then, with all three still held, each sensor is unplugged in stall
mode ``--stalls`` times (and replugged and held again); the Sensor Manager's FAILED says how long the
topic had been silent when it was called stalled (the detection time, from the last message), and the
bench sets that beside the sensor's nominal period.

Goals (issue: adaptive stall detection): a stall caught within 3 nominal periods (100 ms at 30 Hz, 120 ms at
25 Hz); 0 false FAILED in a 10-minute nominal run with 2 CPU hogs.

Prints a markdown table and writes bench/results/stall.json.
Usage: python bench/bench_stall.py [--minutes M] [--stalls N] [--hogs N]
"""
import argparse
import json
import os
import re
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from common import cpu_hogs, loopback_master, print_table, stop_hogs  # noqa: E402

# sensor, device (cable), topic type, sensor type, executable, nominal Hz
SENSORS = [('realsense_d435', 'd435', 'camera_data', 'depth camera', 'd435_driver', 30.0),
           ('sick_lms511', 'sick', 'lidar_data', 'lidar', 'sick_driver', 25.0),
           ('hokuyo_utm30lx', 'hokuyo', 'lidar_data', 'lidar', 'hokuyo.launch', 40.0)]
PERIODS_GOAL = 3.0
SILENCE = re.compile(r'for ([0-9.]+) s \(')


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--minutes', type=float, default=10.0, help='nominal run with every sensor held')
    ap.add_argument('--stalls', type=int, default=10, help='stall unplugs per sensor')
    ap.add_argument('--hogs', type=int, default=2, help='busy-looping processes beside the stack')
    opts = ap.parse_args(argv)
    ros, launcher = loopback_master('bench_stall_')
    busy = []
    false_failed, detections, limits, nominal_false = [], {s[0]: [] for s in SENSORS}, {}, 0
    try:
        import rospy
        from temoto_core.msg import ResourceStatus
        from temoto_testing import sensor_manager as t
        from temoto_sensor_manager.interface import SensorManagerInterface
        rospy.init_node('bench_stall', disable_signals=True)
        print('bench_stall: starting the simulation and the managers ...', flush=True)
        t.start_robot(launcher, launcher.workdir)
        sm = SensorManagerInterface()
        events = []
        sm.register_update_callback(events.append)       # no reload: a FAILED is counted, not repaired

        def hold(sensor):
            name, _, key, kind, exe, _ = sensor
            return sm.start_sensor(kind, [key], executable=exe)

        def learnt(name, timeout=30.0):
            """Wait until the manager watches ``name`` with a limit learnt from its rhythm (below the
            catalogue's, which holds while it learns); a stream too irregular keeps the catalogue's."""
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                entry = t.catalogue()[name]
                cap = min(v['stall_limit'] for v in entry['output_topics'].values())
                if entry['watched'] and max(entry['watched'].values()) < cap:
                    return
                time.sleep(0.5)

        busy = cpu_hogs(opts.hogs)
        held = {s[0]: hold(s) for s in SENSORS}
        print('bench_stall: %d sensors held beside %d CPU hogs for %.1f min ...' % (len(held), len(busy),
                                                                                  opts.minutes), flush=True)
        end = time.monotonic() + opts.minutes * 60
        samples = {s[0]: [] for s in SENSORS}
        while time.monotonic() < end:
            time.sleep(min(10.0, max(0.0, end - time.monotonic())))
            cat = t.catalogue()
            for s in SENSORS:
                samples[s[0]].extend(cat[s[0]]['watched'].values())
            bad = [e for e in events if e.code == ResourceStatus.FAILED]
            print('  %.0f s left: %d FAILED' % (max(0.0, end - time.monotonic()), len(bad)), flush=True)
        false_failed = [e.message for e in events if e.code == ResourceStatus.FAILED]
        nominal_false = len(false_failed)
        limits = {k: (min(v), statistics.median(v), max(v)) for k, v in samples.items() if v}
        # stalls under the same load: every sensor stays held, the stalled one is replugged and held again
        for s in SENSORS:
            name, device, _, _, _, _ = s
            for i in range(opts.stalls):
                learnt(name)
                del events[:]
                t.set_cable(device, 'unplugged', 'stall')
                deadline = time.monotonic() + 10.0

                def of_it():
                    return [e for e in events if e.code == ResourceStatus.FAILED and e.resource_id == held[name].resource_id]
                while time.monotonic() < deadline and not of_it():
                    time.sleep(0.01)
                failed = of_it()
                # a FAILED of a sensor that was not unplugged is a false one
                false_failed.extend(e.message for e in events if e.code == ResourceStatus.FAILED and e not in failed)
                t.set_cable(device, 'plugged')
                sm.stop_sensor(held[name].resource_id)
                held[name] = hold(s)
                if not failed:
                    print('  %s stall %d: no FAILED within 10 s' % (name, i + 1), flush=True)
                    continue
                found = SILENCE.search(failed[0].message)
                detections[name].append(float(found.group(1)) if found else float('nan'))
                print('  %s stall %d/%d: silent %.3f s when called stalled (%s)' % (
                    name, i + 1, opts.stalls, detections[name][-1], failed[0].message.split(': ', 1)[0]),
                    flush=True)
        for result in held.values():
            sm.stop_sensor(result.resource_id)
    finally:
        stop_hogs(busy)
        launcher.stop_all()
        ros.stop()

    rows = []
    for name, _, _, _, _, rate in SENSORS:
        d = detections[name]
        if d:
            med, worst = statistics.median(d), max(d)
            rows.append(('stall caught, %s (%.0f Hz), from its last message, n=%d' % (name, rate, len(d)),
                         'median %.0f ms (%.1f periods), max %.0f ms (%.1f periods)'
                         % (med * 1e3, med * rate, worst * 1e3, worst * rate),
                         '<= %.0f ms (3 periods)' % (PERIODS_GOAL / rate * 1e3)))
        if name in limits:
            lo, med, hi = limits[name]
            rows.append(('limit in use during the nominal run, %s' % name,
                         'min %.0f / median %.0f / max %.0f ms' % (lo * 1e3, med * 1e3, hi * 1e3), '-'))
    rows.append(('false FAILED in %.1f min, 3 sensors held, %d CPU hogs' % (opts.minutes, opts.hogs),
                 '%d (and %d during the stalls)' % (nominal_false, len(false_failed) - nominal_false), '0 (10 min)'))
    print_table('Stall detection', rows)
    for message in false_failed:
        print('false FAILED: %s' % message)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'stall.json'), 'w') as f:
        json.dump({'rows': rows, 'false_failed': false_failed,
                   'detections_s': detections, 'minutes': opts.minutes}, f, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
