#!/usr/bin/env python3
"""ER Manager benchmark: failure-detection latency and load latency.

1. Detection latency: a node held by a consumer one hop away (a Resource
   Registrar in this process) is SIGKILLed; measured from the kill to the FAILED
   status callback at the consumer. Goal: median <= 20 ms (the original polled
   every 1 s).
2. Load latency of a trivial rospy node until it is registered at the master:
   through the ER Manager (load_process call until its response, which returns
   only after registration) against a bare ``rosrun`` of the same node polled
   at the master with the manager's own period (20 ms).
3. The same two figures for a launch file of two such nodes
   (test_nodes/launch/er_bench_two.launch), which the ER Manager starts natively
   (one supervised process per node): SIGKILL of one node to FAILED at the
   consumer (goal: median <= 20 ms, as for a node), and the load until both
   nodes are registered against ``roslaunch`` of the same file measured the same way.

4. Preloading (``~preload_python``): load latency with Python nodes started
   plainly against forked from the manager's zygote, for the trivial node, the
   two-node launch file and vaultbot_sim's ``hokuyo.launch`` (hokuyo_driver +
   laser_stitcher, the failover demo's substitute sensor). Two managers run side
   by side (one per mode) and their loads alternate, so machine load hits both
   alike. Also the interpreter start and ``import rospy, numpy, std_msgs.msg,
   sensor_msgs.msg`` in a fresh process, which is what the zygote saves.

Prints a markdown table and writes bench/results/er.json.
Usage: python bench/bench_er.py [--kills N] [--loads N] [--preload-loads N] [--preload-only]
"""
import argparse
import itertools
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import xmlrpc.client

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from common import pct  # noqa: E402

from temoto_testing import FirstFailure, ProcessGroupLauncher, RosMaster  # noqa: E402
from temoto_core import master_lookup as er_master  # noqa: E402

POLL = 0.02
LAUNCH = 'er_bench_two.launch'


def summary(values):
    return {'n': len(values), 'median_ms': statistics.median(values) * 1e3, 'p90_ms': pct(values, 90) * 1e3,
            'min_ms': min(values) * 1e3, 'max_ms': max(values) * 1e3}


def wait_registered(master, names, proc, timeout=20.0):
    names = [names] if isinstance(names, str) else list(names)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError('%s exited with %s' % (proc.args[0], proc.returncode))
        if all(master.lookupNode('/bench', n)[0] == 1 for n in names):
            return
        time.sleep(POLL)
    raise TimeoutError(', '.join(names))


def node_pid(master_uri, name):
    uri = er_master.lookup_node(master_uri, name)
    pid = er_master.node_pid(uri) if uri else None
    if pid is None:
        raise RuntimeError('%s is not registered' % name)
    return pid


def stop_group(proc):
    os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(15)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(5)


PRELOAD_CASES = [  # figure key, package, executable, args, node names (relative to the load's namespace)
    ('node', 'temoto_er_manager', 'er_minimal_node', '__name:=pre_node', ['pre_node']),
    ('two_node_launch', 'temoto_er_manager', LAUNCH, '', ['alpha', 'beta']),
    ('hokuyo_launch', 'vaultbot_sim', 'hokuyo.launch', '', ['hokuyo_driver', 'laser_stitcher']),
]
IMPORTS = 'import rospy, numpy, std_msgs.msg, sensor_msgs.msg'


def fresh_interpreter(code, n):
    """Seconds to run ``python -c code`` in a fresh process, ``n`` times."""
    out = []
    for _ in range(n):
        t0 = time.monotonic()
        subprocess.run([sys.executable, '-c', code], check=True)
        out.append(time.monotonic() - t0)
    return out


def preload_comparison(launcher, work, n):
    """Load latency per case with preloading off and on (two managers, loads alternating)."""
    from temoto_core.rr import ResourceRegistrar
    from temoto_er_manager.srv import LoadProcess
    rrs = {}
    for mode, on in (('off', False), ('on', True)):
        launcher.node('temoto_er_manager', 'temoto_er_manager', name='er_preload_' + mode,
                      params={'log_dir': os.path.join(work, 'er_logs_' + mode), 'temoto_namespace': 'pre_' + mode,
                              'preload_python': 'true' if on else 'false', 'registration_timeout': 20.0})
        rrs[mode] = ResourceRegistrar('bench_preload_' + mode, namespace='pre_' + mode)
    times = {case[0]: {'off': [], 'on': []} for case in PRELOAD_CASES}
    seq = itertools.count(1)
    # one warm-up load per manager and case (the zygote imports while the first load waits; disk caches)
    for i in range(n + 1):
        for key, pkg, exe, args, _nodes in PRELOAD_CASES:
            for mode in (('off', 'on') if i % 2 else ('on', 'off')):
                req = LoadProcess._request_class(action='ros_execute', package_name=pkg, executable=exe, args=args,
                                                 ros_namespace='/p%s_%d' % (mode, next(seq)))
                t0 = time.monotonic()
                resp = rrs[mode].call('temoto_er_manager', 'load_process', req)
                took = time.monotonic() - t0
                rrs[mode].unload(resp.trr.resource_id)
                if i:
                    times[key][mode].append(took)
            if i:
                print('  preload %2d/%d %-16s off %4.0f ms, on %4.0f ms' % (
                    i, n, key, times[key]['off'][-1] * 1e3, times[key]['on'][-1] * 1e3), flush=True)
    # detection through the zygote's exit report against the manager's own pidfd
    for i in range(n):
        for mode in ('off', 'on'):
            req = LoadProcess._request_class(action='ros_execute', package_name='temoto_er_manager',
                                             executable='er_minimal_node', args='__name:=pre_victim_%d' % next(seq))
            times.setdefault('detection', {'off': [], 'on': []})[mode].append(
                detect_once(rrs[mode], req, lambda resp: resp.pid))
    for rr in rrs.values():
        rr.shutdown()
    return times


def detect_once(rr, request, victim_pid):
    """Load ``request``, SIGKILL the pid ``victim_pid(response)`` gives, return seconds to FAILED at ``rr``."""
    failed = FirstFailure()
    resp = rr.call('temoto_er_manager', 'load_process', request, status_cb=failed)
    pid = victim_pid(resp)
    t0 = time.monotonic()
    os.kill(pid, signal.SIGKILL)
    stamp = failed.wait(5.0)
    rr.unload(resp.trr.resource_id)
    return stamp - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--kills', type=int, default=20)
    ap.add_argument('--loads', type=int, default=10)
    ap.add_argument('--preload-loads', type=int, default=10)
    ap.add_argument('--preload-only', action='store_true', help='only section 4 (writes er_preload.json)')
    opts = ap.parse_args(argv)
    work = tempfile.mkdtemp(prefix='bench_er_')
    ros = RosMaster(work).start()
    ros.point_this_process()
    launcher = ProcessGroupLauncher(ros.env, work)
    try:
        import rospy
        rospy.init_node('bench_er', disable_signals=True)
        bare_python = fresh_interpreter('pass', 5)
        bare_imports = fresh_interpreter(IMPORTS, 5)
        preload = preload_comparison(launcher, work, opts.preload_loads)
        if opts.preload_only:
            return report_preload(preload, bare_python, bare_imports, 'er_preload.json')
        launcher.node('temoto_er_manager', 'temoto_er_manager', name='temoto_er_manager',
                      params={'log_dir': os.path.join(work, 'er_logs')})
        from temoto_core.rr import ResourceRegistrar
        from temoto_er_manager.srv import LoadProcess
        rr = ResourceRegistrar('bench_consumer')
        master = xmlrpc.client.ServerProxy(ros.uri)
        names = itertools.count(1)

        # -- 1. detection latency ---------------------------------------------------------------
        detect = []
        for i in range(opts.kills):
            req = LoadProcess._request_class(action='ros_execute', package_name='temoto_er_manager',
                                             executable='er_minimal_node', args='__name:=victim_%d' % next(names))
            detect.append(detect_once(rr, req, lambda resp: resp.pid))
            print('  detection %2d/%d: %.1f ms' % (i + 1, opts.kills, detect[-1] * 1e3), flush=True)

        # -- 2. load latency ---------------------------------------------------------------------
        via_er, bare = [], []
        for i in range(opts.loads):
            name = 'loaded_%d' % next(names)
            req = LoadProcess._request_class(action='ros_execute', package_name='temoto_er_manager',
                                             executable='er_minimal_node', args='__name:=' + name)
            t0 = time.monotonic()
            resp = rr.call('temoto_er_manager', 'load_process', req)
            via_er.append(time.monotonic() - t0)
            rr.unload(resp.trr.resource_id)

            name = 'bare_%d' % next(names)
            t0 = time.monotonic()
            proc = subprocess.Popen(['rosrun', 'temoto_er_manager', 'er_minimal_node', '__name:=' + name],
                                    env=ros.env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT,
                                    start_new_session=True)
            try:
                wait_registered(master, '/' + name, proc)
                bare.append(time.monotonic() - t0)
            finally:
                stop_group(proc)
            print('  load %2d/%d: ER %.0f ms, rosrun %.0f ms' % (i + 1, opts.loads, via_er[-1] * 1e3,
                                                               bare[-1] * 1e3), flush=True)

        # -- 3. launch file: detection and load latency --------------------------------------------
        launch_detect = []
        for i in range(opts.kills):
            ns = '/ld_%d' % next(names)
            req = LoadProcess._request_class(action='ros_execute', package_name='temoto_er_manager',
                                             executable=LAUNCH, ros_namespace=ns)
            # the second node: the first is the response's pid, so this is the case a launch wrapper hid
            launch_detect.append(detect_once(rr, req, lambda resp, ns=ns: node_pid(ros.uri, ns + '/beta')))
            print('  launch detection %2d/%d: %.1f ms' % (i + 1, opts.kills, launch_detect[-1] * 1e3), flush=True)
        launch_er, launch_bare = [], []
        for i in range(opts.loads):
            ns = '/ll_%d' % next(names)
            req = LoadProcess._request_class(action='ros_execute', package_name='temoto_er_manager',
                                             executable=LAUNCH, ros_namespace=ns)
            t0 = time.monotonic()
            resp = rr.call('temoto_er_manager', 'load_process', req)
            launch_er.append(time.monotonic() - t0)
            rr.unload(resp.trr.resource_id)

            ns = '/lb_%d' % next(names)
            t0 = time.monotonic()
            proc = subprocess.Popen(['roslaunch', 'temoto_er_manager', LAUNCH], env=dict(ros.env, ROS_NAMESPACE=ns),
                                    stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True)
            try:
                wait_registered(master, [ns + '/alpha', ns + '/beta'], proc)
                launch_bare.append(time.monotonic() - t0)
            finally:
                stop_group(proc)
            print('  launch load %2d/%d: ER %.0f ms, roslaunch %.0f ms' % (i + 1, opts.loads, launch_er[-1] * 1e3,
                                                                         launch_bare[-1] * 1e3), flush=True)
        rr.shutdown()
    finally:
        launcher.stop_all()
        ros.stop()

    results = {'detection_latency': summary(detect), 'load_via_er_manager': summary(via_er),
               'load_bare_rosrun': summary(bare), 'launch_detection_latency': summary(launch_detect),
               'launch_load_via_er_manager': summary(launch_er), 'launch_load_roslaunch': summary(launch_bare),
               'goal_detection_median_ms': 20.0, 'machine': {'cpus': os.cpu_count()}, 'time': time.time()}
    d, e, b = results['detection_latency'], results['load_via_er_manager'], results['load_bare_rosrun']
    ld, le, lb = (results['launch_detection_latency'], results['launch_load_via_er_manager'],
                  results['launch_load_roslaunch'])
    print()
    print('| figure | value | goal |')
    print('| --- | --- | --- |')
    print('| detection latency, SIGKILL to FAILED at a consumer one hop away (n=%d) | median %.1f ms, p90 %.1f ms, '
          'max %.1f ms | median <= 20 ms |' % (d['n'], d['median_ms'], d['p90_ms'], d['max_ms']))
    print('| load of a trivial rospy node until registered, via the ER Manager (n=%d) | median %.0f ms, p90 %.0f ms '
          '| close to bare rosrun |' % (e['n'], e['median_ms'], e['p90_ms']))
    print('| same node, bare `rosrun`, registration polled every 20 ms (n=%d) | median %.0f ms, p90 %.0f ms | '
          'reference |' % (b['n'], b['median_ms'], b['p90_ms']))
    print('| launch file of 2 nodes: SIGKILL of its second node to FAILED at a consumer one hop away (n=%d) | '
          'median %.1f ms, p90 %.1f ms, max %.1f ms | median <= 20 ms |'
          % (ld['n'], ld['median_ms'], ld['p90_ms'], ld['max_ms']))
    print('| load of that launch file until both nodes are registered, via the ER Manager (n=%d) | median %.0f ms, '
          'p90 %.0f ms | below roslaunch |' % (le['n'], le['median_ms'], le['p90_ms']))
    print('| same file, `roslaunch`, registrations polled every 20 ms (n=%d) | median %.0f ms, p90 %.0f ms | '
          'reference |' % (lb['n'], lb['median_ms'], lb['p90_ms']))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'er.json'), 'w') as f:
        json.dump(results, f, indent=2, sort_keys=True)
    ok = report_preload(preload, bare_python, bare_imports, None, results)
    return 0 if d['median_ms'] <= 20.0 and ld['median_ms'] <= 20.0 and ok == 0 else 1


def report_preload(times, bare_python, bare_imports, filename, results=None):
    """Print section 4 (preload off vs on) and store it (in ``results`` and er.json, or in ``filename``)."""
    out = {'fresh_python_ms': summary(bare_python), 'fresh_python_with_imports_ms': summary(bare_imports),
           'preload_modules_imported': IMPORTS}
    print()
    print('| preloading: load until every node is registered | plain start | from the zygote | goal |')
    print('| --- | --- | --- | --- |')
    worse = False
    for key, _pkg, exe, _args, nodes in PRELOAD_CASES:
        off, on = summary(times[key]['off']), summary(times[key]['on'])
        out['load_%s' % key] = {'plain': off, 'preload': on}
        worse |= on['median_ms'] >= off['median_ms']
        print('| %s (%s), n=%d | median %.0f ms, p90 %.0f ms | median %.0f ms, p90 %.0f ms | noticeably lower |'
              % (exe, ', '.join(nodes), off['n'], off['median_ms'], off['p90_ms'], on['median_ms'], on['p90_ms']))
    print('| fresh `python -c pass` / `python -c "%s"` (n=%d) | median %.0f ms / %.0f ms | (saved by the zygote) '
          '| reference |' % (IMPORTS, len(bare_python), statistics.median(bare_python) * 1e3,
                             statistics.median(bare_imports) * 1e3))
    det_off, det_on = summary(times['detection']['off']), summary(times['detection']['on'])
    out['detection_latency'] = {'plain': det_off, 'preload': det_on}
    print('| detection latency, SIGKILL of a node to FAILED at a consumer one hop away (n=%d) | median %.1f ms, '
          'max %.1f ms | median %.1f ms, max %.1f ms | median <= 20 ms |'
          % (det_off['n'], det_off['median_ms'], det_off['max_ms'], det_on['median_ms'], det_on['max_ms']))
    worse |= det_on['median_ms'] > 20.0
    if results is not None:
        results['preload'] = out
        path = os.path.join(ROOT, 'bench', 'results', 'er.json')
        with open(path, 'w') as f:
            json.dump(results, f, indent=2, sort_keys=True)
    else:
        os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
        with open(os.path.join(ROOT, 'bench', 'results', filename), 'w') as f:
            json.dump(dict(out, time=time.time(), machine={'cpus': os.cpu_count()}), f, indent=2, sort_keys=True)
    return 1 if worse else 0


if __name__ == '__main__':
    sys.exit(main())
