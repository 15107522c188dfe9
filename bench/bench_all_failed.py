#!/usr/bin/env python3
"""Every device of the view unplugged one right after another: how long until the action says so.

Each run is ``temoto demo --unplug-all`` (its own roscore, headless RViz): once the RGB-D cloud is on
screen, the D435 is unplugged (crash), the Hokuyo (stall) and the SICK (crash), one right after another.
The figure is the action's ``all_failed`` event after the last unplug. Goal: <= 3 s. It was 12.1 s when
each candidate silent from its start cost its whole first-data allowance; the drivers now report a
missing device on /diagnostics, and the Sensor Manager fails the candidate on that report.

Writes bench/results/all_failed.json. Usage: python bench/bench_all_failed.py [--runs N]
"""
import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'bench'))
from bench_demo import one_run  # noqa: E402

GOAL_S = 3.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--runs', type=int, default=5)
    opts = ap.parse_args()
    base = tempfile.mkdtemp(prefix='bench_all_failed_')
    took = []
    try:
        for i in range(opts.runs):
            r = one_run(os.path.join(base, 'run%02d' % i), ['--unplug-all', '--no-report'])
            if r.get('all_failed_s') is not None:
                took.append(r['all_failed_s'])
            print('  run %d/%d: rc %d, every sensor failed after %s' % (
                i + 1, opts.runs, r['rc'], '-' if r.get('all_failed_s') is None else '%.2f s' % r['all_failed_s']),
                flush=True)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    took.sort()
    summary = {'runs': opts.runs, 'measured': len(took), 'values_s': took, 'goal_s': GOAL_S,
               'median_s': statistics.median(took) if took else None, 'max_s': max(took) if took else None}
    print()
    print('| figure | value | goal |')
    print('| --- | --- | --- |')
    if took:
        print('| D435 crash, Hokuyo stall, SICK crash, one right after another: last unplug → the action\'s '
              '"every sensor failed" (n=%d) | median %.2f s, max %.2f s (before: 12.1 s) | ≤ %.0f s |'
              % (len(took), summary['median_s'], summary['max_s'], GOAL_S))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'all_failed.json'), 'w') as f:
        json.dump(summary, f, indent=2)
    return 0 if len(took) == opts.runs else 1


if __name__ == '__main__':
    sys.exit(main())
