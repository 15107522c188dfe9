#!/usr/bin/env python3
"""RViz host start-up under CPU load: how many cold starts crash before the host is ready.

Each start is a fresh host process (its own Xvfb), on a private roscore, with CPU-bound hog processes
beside it; a start counts as ready once the host's services answer (it offers them only after RViz
has drawn its first frames). Variants (environment settings for the host) alternate start by start,
so that every variant meets the same load.

Prints a markdown table and writes bench/results/host_start.json.
Usage: python bench/bench_host_start.py [--starts N] [--hogs H] [--variant NAME=VAR=VALUE ...]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from temoto_testing import ProcessGroupLauncher, RosMaster  # noqa: E402


def mesa_version() -> str:
    out = subprocess.run(['dpkg-query', '-W', '-f=${Version}', 'libgl1-mesa-dri'], capture_output=True, text=True)
    return out.stdout.strip() or 'unknown'


def parse_variants(specs):
    variants = {'default': {}}
    for spec in specs:
        name, _, setting = spec.partition('=')
        key, _, value = setting.partition('=')
        if not name or not key:
            raise SystemExit('--variant takes NAME=VAR=VALUE, got %r' % spec)
        variants.setdefault(name, {})[key] = value
    return variants


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--starts', type=int, default=100, help='cold starts per variant (default 100)')
    parser.add_argument('--hogs', type=int, default=2, help='CPU-bound processes beside the host (default 2)')
    parser.add_argument('--variant', action='append', default=[], help='NAME=VAR=VALUE: an environment variant')
    args = parser.parse_args(argv)
    variants = parse_variants(args.variant)
    work = tempfile.mkdtemp(prefix='bench_host_start_')
    ros = RosMaster(work).start()
    os.environ.update(ros.env)
    hogs = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(args.hogs)]
    tally = {name: {'ready': 0, 'crashed': 0, 'returncodes': []} for name in variants}
    try:
        import rospy
        from temoto_output_manager.host_client import RvizHostClient
        rospy.init_node('bench_host_start', disable_signals=True)
        for i in range(args.starts * len(variants)):
            name = list(variants)[i % len(variants)]
            launcher = ProcessGroupLauncher(dict(ros.env, **variants[name]), work)
            proc = None
            try:
                proc = launcher.node('temoto_output_manager', 'rviz_host', name='host_%d' % i, namespace='bench',
                                     params={'show_robot': 'false', 'show_grid': 'false'}, timeout=60)
                RvizHostClient('/bench/host_%d' % i).wait_ready(
                    60, failed=lambda: None if proc.alive() else 'rc %s' % proc.returncode)
                tally[name]['ready'] += 1
            except Exception:
                tally[name]['crashed'] += 1
                tally[name]['returncodes'].append(proc.returncode if proc is not None else None)
            finally:
                launcher.stop_all()
            if (i + 1) % 20 == 0:
                print('  %d starts: %s' % (i + 1, {n: t['crashed'] for n, t in tally.items()}), flush=True)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
        ros.stop()
    mesa = mesa_version()
    print('\n| RViz host cold starts beside %d CPU hogs (Mesa %s) | ready | crashed before ready | goal |'
          % (args.hogs, mesa))
    print('| --- | --- | --- | --- |')
    for name, t in tally.items():
        print('| %s %s | %d | %d | 0 |' % (name, ' '.join('%s=%s' % kv for kv in variants[name].items()),
                                          t['ready'], t['crashed']))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'host_start.json'), 'w') as f:
        json.dump({'mesa': mesa, 'hogs': args.hogs, 'starts_per_variant': args.starts, 'variants': variants,
                   'tally': tally, 'time': time.time()}, f, indent=2, sort_keys=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
