#!/usr/bin/env python3
"""Output Manager benchmark: time to the first drawn frame, and the RViz host's CPU.

1. From the ``load_rviz_plugin`` call (OutputManagerInterface.show) to the
   display's ``first_frame`` event (RViz's own message count, then the next
   rendered frame; stamped by the host), for a cold host (the call starts the
   host through the ER Manager, under its own Xvfb) and a warm host (another
   display keeps the host alive).
2. CPU of the host process (and of its Xvfb) while it shows a D435-like
   424x240 RGB cloud published at 30 Hz (the simulation's rate), with the
   default settings (anti-aliasing off, Frame Rate 15, the cloud drawn as 3-pixel points: DEFAULT_CONFIG).

Prints a markdown table and writes bench/results/output.json.
Usage: python bench/bench_output.py [--cold N] [--warm N] [--cpu-seconds S]
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

from temoto_testing import ProcessGroupLauncher, RosMaster, wait_for  # noqa: E402
from temoto_core import master_lookup as er_master  # noqa: E402

NS = 'temoto'
HOST = '/%s/rviz_host' % NS
TOPIC = '/bench/d435/points'


def host_pid():
    """The RViz host's pid, or None while no live host is registered."""
    uri = er_master.lookup_node(os.environ['ROS_MASTER_URI'], HOST)
    return er_master.node_pid(uri) if uri else None


def first_frame_seconds(om, events, name_hint, t_call_wall):
    """Wait for the display's first_frame event; seconds from the call to the drawn frame (host stamp)."""
    ev = wait_for(lambda: next((e for e in list(events) if e.event == 'first_frame' and e.display_name == name_hint),
                               None), 30, 'first frame of %s' % name_hint)
    return ev.header.stamp.to_sec() - t_call_wall


def cpu_percent(proc, seconds):
    t0, c0 = time.monotonic(), sum(proc.cpu_times()[:2])
    time.sleep(seconds)
    return 100.0 * (sum(proc.cpu_times()[:2]) - c0) / (time.monotonic() - t0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--cold', type=int, default=3)
    parser.add_argument('--warm', type=int, default=5)
    parser.add_argument('--cpu-seconds', type=float, default=10.0)
    args = parser.parse_args(argv)
    work = tempfile.mkdtemp(prefix='bench_output_')
    ros = RosMaster(work).start()
    os.environ.update(ros.env)
    launcher = ProcessGroupLauncher(ros.env, work)
    results = {}
    try:
        import psutil
        import rospy
        from temoto_output_manager import sample_data as sd
        from temoto_output_manager.interface import OutputManagerInterface
        from temoto_output_manager.msg import DisplayEvent
        launcher.node('temoto_er_manager', 'temoto_er_manager', name='temoto_er_manager',
                      params={'registration_timeout': 20.0, 'log_dir': work})
        launcher.node('temoto_output_manager', 'temoto_output_manager', name='temoto_output_manager')
        rospy.init_node('bench_output', disable_signals=True)
        events = []
        rospy.Subscriber('/%s/temoto_output_manager/display_events' % NS, DisplayEvent, events.append)
        om = OutputManagerInterface(namespace=NS)
        om.register_update_callback(lambda ev: None)
        pub = sd.RepeatingPublisher(TOPIC, sd.cloud_msg(width=424, height=240), 30).start()
        wait_for(lambda: pub.count > 10, 10, 'cloud publisher running')

        def one_show(name):
            events.clear()
            t_wall = time.time()
            t0 = time.monotonic()
            resp = om.show('point cloud', TOPIC, name=name)
            call = time.monotonic() - t0
            return resp, call, first_frame_seconds(om, events, name, t_wall)

        cold, cold_call = [], []
        for i in range(args.cold):
            print('cold host %d/%d ...' % (i + 1, args.cold), flush=True)
            resp, call, ff = one_show('cold %d' % i)
            cold.append(ff)
            cold_call.append(call)
            om.hide(resp.trr.resource_id)
            wait_for(lambda: host_pid() is None, 20, 'host to stop')
        keeper = om.show_in_rviz('tf')                 # keeps the host warm
        warm, warm_call = [], []
        for i in range(args.warm):
            print('warm host %d/%d ...' % (i + 1, args.warm), flush=True)
            resp, call, ff = one_show('warm %d' % i)
            warm.append(ff)
            warm_call.append(call)
            if i < args.warm - 1:
                om.hide(resp.trr.resource_id)
        print('host CPU while showing a 424x240 cloud at 30 Hz (%.0f s) ...' % args.cpu_seconds, flush=True)
        host = psutil.Process(host_pid())
        xvfb = [c for c in host.children() if c.name() == 'Xvfb']
        time.sleep(2.0)                                 # settle after the last add
        c_xvfb0 = sum(xvfb[0].cpu_times()[:2]) if xvfb else 0.0
        t0 = time.monotonic()
        host_cpu = cpu_percent(host, args.cpu_seconds)
        xvfb_cpu = 100.0 * (sum(xvfb[0].cpu_times()[:2]) - c_xvfb0) / (time.monotonic() - t0) if xvfb else 0.0
        rate = pub.count
        rss = host.memory_info().rss / 1e6
        om.hide(resp.trr.resource_id)
        om.hide(keeper)
        pub.stop()
        om.shutdown()
        results = {
            'first_frame_cold_s': {'median': statistics.median(cold), 'max': max(cold), 'runs': cold},
            'first_frame_warm_s': {'median': statistics.median(warm), 'max': max(warm), 'runs': warm},
            'load_call_cold_s': statistics.median(cold_call), 'load_call_warm_s': statistics.median(warm_call),
            'host_cpu_percent_one_core': host_cpu, 'xvfb_cpu_percent_one_core': xvfb_cpu,
            'host_rss_mb': rss, 'cloud': '424x240 xyz+rgb at 30 Hz', 'frame_rate_cap': 15, 'anti_aliasing': False,
            'style': 'Points, 3 px',
            'machine_cores': os.cpu_count(),
        }
    finally:
        launcher.stop_all()
        ros.stop()
    rows = [
        ('load_rviz_plugin → first frame drawn, cold host (median of %d)' % args.cold,
         '%.2f s (max %.2f)' % (results['first_frame_cold_s']['median'], results['first_frame_cold_s']['max']),
         '≤ 3 s'),
        ('load_rviz_plugin → first frame drawn, warm host (median of %d)' % args.warm,
         '%.3f s (max %.3f)' % (results['first_frame_warm_s']['median'], results['first_frame_warm_s']['max']),
         '≤ 0.5 s'),
        ('load_rviz_plugin call returns, cold / warm', '%.2f s / %.3f s' % (results['load_call_cold_s'],
                                                                          results['load_call_warm_s']), '-'),
        ('RViz host CPU, 424x240 cloud at 30 Hz, cap 15 fps, no AA, 3 px points', '%.0f %% of one core' %
         results['host_cpu_percent_one_core'], '≤ 70 %'),
        ('its Xvfb CPU', '%.0f %%' % results['xvfb_cpu_percent_one_core'], '-'),
        ('RViz host RSS', '%.0f MB' % results['host_rss_mb'], '-'),
    ]
    print('\n| figure | value | goal |\n| --- | --- | --- |')
    for r in rows:
        print('| %s | %s | %s |' % r)
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'output.json'), 'w') as f:
        json.dump(results, f, indent=2, sort_keys=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
