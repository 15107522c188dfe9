#!/usr/bin/env python3
"""Benchmark of the simulated VaultBot's drivers, against the real devices' rates.

For each driver alone, then all three together (plus the laser stitcher):
achieved rate, CPU share (of one core) of the driver process, and the time from
starting the process to its first message. Then the time from an unplug
(crash mode) to the driver's exit, whose goal is 100 ms.
Prints a markdown table and writes bench/results/sim.json.

Usage: source env.sh && python bench/bench_sim.py [--window SECONDS]
"""
import argparse
import json
import os
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import psutil  # noqa: E402

from temoto_testing import ProcessGroupLauncher, RosMaster, wait_for  # noqa: E402

DRIVERS = {  # driver: (topic, message type, real device rate)
    'd435_driver': ('/d435/depth_registered/points', 'sensor_msgs/PointCloud2', 30.0),
    'hokuyo_driver': ('/hokuyo/scan', 'sensor_msgs/LaserScan', 40.0),
    'sick_driver': ('/sick/scan', 'sensor_msgs/LaserScan', 25.0),
}
DEVICE = {'d435_driver': 'd435', 'hokuyo_driver': 'hokuyo', 'sick_driver': 'sick'}


class Counter:
    def __init__(self, rospy, topic, msg_type):
        self.times = []
        self.lock = threading.Lock()
        self.sub = rospy.Subscriber(topic, msg_type, self._cb, queue_size=50, buff_size=2 ** 24,
                                    tcp_nodelay=True)

    def _cb(self, _msg):
        with self.lock:
            self.times.append(time.monotonic())

    def first_after(self, t):
        with self.lock:
            return next((x for x in self.times if x >= t), None)

    def count_between(self, a, b):
        with self.lock:
            return sum(1 for x in self.times if a <= x < b)


def measure(procs, counters, names, window):
    """Start `names`, wait for first messages, then measure rate and CPU over `window` s."""
    started, first = {}, {}
    for n in names:
        t = time.monotonic()
        started[n] = (procs.node('vaultbot_sim', n), t)
    for n in names:
        proc, t = started[n]
        wait_for(lambda: counters[n].first_after(t), 60, f'{n} first message')
        first[n] = counters[n].first_after(t) - t
    ps = {n: psutil.Process(started[n][0].pid) for n in names}
    def cpu(n):  # the driver and its children (the D435's render worker)
        procs_ = [ps[n]] + ps[n].children(recursive=True)
        return sum(sum(p.cpu_times()[:2]) for p in procs_)

    cpu0 = {n: cpu(n) for n in names}
    t0 = time.monotonic()
    wait_for(lambda: time.monotonic() - t0 >= window, window + 5, 'measuring window')
    t1 = time.monotonic()
    out = {}
    for n in names:
        share = (cpu(n) - cpu0[n]) / (t1 - t0)
        out[n] = {'rate_hz': counters[n].count_between(t0, t1) / (t1 - t0), 'cpu_share': share,
                  'first_message_s': first[n], 'real_rate_hz': DRIVERS[n][2]}
    return out, {n: started[n][0] for n in names}


def crash_latency(rospy, proc, device):
    from vaultbot_sim.srv import SetDeviceState
    call = rospy.ServiceProxy('/vaultbot_sim/set_device_state', SetDeviceState)
    t = time.monotonic()
    call(device, 'unplugged', 'crash')
    try:
        rc = proc.proc.wait(timeout=5)
    except Exception:
        rc = None
    dt = time.monotonic() - t
    call(device, 'plugged', '')
    return dt, rc


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--window', type=float, default=6.0)
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix='bench_sim_')
    master = RosMaster(work).start()
    master.point_this_process()
    procs = ProcessGroupLauncher(master.env, work)
    results = {'cores': psutil.cpu_count(), 'window_s': args.window, 'alone': {}, 'together': {}, 'crash_exit_s': {}}
    try:
        import rospy
        import roslib.message
        rospy.init_node('bench_sim', anonymous=True, disable_signals=True)
        counters = {n: Counter(rospy, topic, roslib.message.get_message_class(t))
                    for n, (topic, t, _) in DRIVERS.items()}
        procs.node('vaultbot_sim', 'vaultbot_sim', params={'world': 'lab'})
        for n in DRIVERS:
            print(f'bench: {n} alone ({args.window:.0f} s)...', flush=True)
            out, started = measure(procs, counters, [n], args.window)
            results['alone'].update(out)
            started[n].stop()
        print(f'bench: all drivers together + laser_stitcher ({args.window:.0f} s)...', flush=True)
        procs.node('vaultbot_sim', 'laser_stitcher')
        out, started = measure(procs, counters, list(DRIVERS), args.window)
        results['together'].update(out)
        for n, proc in started.items():
            dt, rc = crash_latency(rospy, proc, DEVICE[n])
            results['crash_exit_s'][n] = {'seconds': dt, 'returncode': rc}
        rospy.signal_shutdown('bench done')
    finally:
        procs.stop_all()
        master.stop()

    rows = ['| driver | real rate | alone: rate | alone: CPU | together: rate | together: CPU | start → first msg | unplug(crash) → exit (goal 100 ms) |',
            '| --- | --- | --- | --- | --- | --- | --- | --- |']
    for n in DRIVERS:
        a, t, c = results['alone'][n], results['together'][n], results['crash_exit_s'][n]
        rows.append(f"| {n} | {a['real_rate_hz']:.0f} Hz | {a['rate_hz']:.1f} Hz | {100 * a['cpu_share']:.0f} % | "
                    f"{t['rate_hz']:.1f} Hz | {100 * t['cpu_share']:.0f} % | {a['first_message_s']:.2f} s | "
                    f"{1000 * c['seconds']:.0f} ms (rc {c['returncode']}) |")
    print('\n'.join(rows))
    print(f"\nCPU share is of one core; the machine has {results['cores']} cores.")
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'sim.json'), 'w') as f:
        json.dump(results, f, indent=2)
    return 0


if __name__ == '__main__':
    sys.exit(main())
