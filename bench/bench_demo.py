#!/usr/bin/env python3
"""Demo benchmark: the display gap per failure, median over N whole demo runs (cold drivers each time).

Each run is ``temoto demo`` as a user starts it (its own roscore, headless RViz), so every failover
includes the real cold start of the substitute driver. Figures come from each run's bag
(``report.json``, computed with rosbags):
- display gap: last frame of the failed sensor's stream -> first frame of its substitute drawn in RViz.
  Goal: median <= 0.8 s.
- detection latency (unplug -> first FAILED), propagation (FAILED -> the action) and switch time
  (unplug -> substitute drawn), for the breakdown; and the whole run's wall time (goal < 90 s).

Prints a markdown table and writes bench/results/demo.json.
Usage: python bench/bench_demo.py [--runs N] [--keep DIR]
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Sequence

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from common import child_env  # noqa: E402
GAP_GOAL_S = 0.8
RUN_GOAL_S = 90.0
FIGURES = ('display_gap_s', 'detection_s', 'propagation_s', 'switch_s')


def one_run(out: str, args: Sequence[str] = ()) -> dict:
    """``temoto demo --out out ARGS`` in a child process, as a user starts it; its rc, wall time and report's
    failures (and fail-backs)."""
    env = child_env()
    t = time.monotonic()
    proc = subprocess.run([sys.executable, '-m', 'temoto_bringup.cli', 'demo', '--out', out] + list(args), env=env,
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    wall = time.monotonic() - t
    result = {'rc': proc.returncode, 'wall_s': wall, 'failures': [], 'failbacks': []}
    try:
        with open(os.path.join(out, 'demo.json')) as f:
            result['all_failed_s'] = json.load(f).get('all_failed_s')
    except (OSError, ValueError):
        pass
    try:
        with open(os.path.join(out, 'report.json')) as f:
            report = json.load(f)
        result['failures'] = report['failures']
        result['failbacks'] = report.get('failbacks', [])
    except (OSError, ValueError, KeyError):
        result['error'] = proc.stderr[-2000:]
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--runs', type=int, default=5)
    ap.add_argument('--keep', default='', help='keep the run folders here')
    opts = ap.parse_args()
    base = opts.keep or tempfile.mkdtemp(prefix='bench_demo_')
    runs = []
    for i in range(opts.runs):
        r = one_run(os.path.join(base, 'run%02d' % i))
        runs.append(r)
        gaps = ', '.join('%s %s' % (f['device'], '-' if f['display_gap_s'] is None else '%.2f s' % f['display_gap_s'])
                         for f in r['failures'])
        print('  run %d/%d: rc %d, %.1f s; display gap %s' % (i + 1, opts.runs, r['rc'], r['wall_s'], gaps or '-'),
              flush=True)
    if not opts.keep:
        shutil.rmtree(base, ignore_errors=True)

    per_failure = {}
    for r in runs:
        for f in r['failures']:
            key = '%s (%s)' % (f['device'], f['mode'])
            d = per_failure.setdefault(key, {k: [] for k in FIGURES})
            for k in FIGURES:
                if f.get(k) is not None:
                    d[k].append(f[k])
    ok_runs = [r for r in runs if r['rc'] == 0]
    summary = {'runs': len(runs), 'ok_runs': len(ok_runs), 'goal_display_gap_median_s': GAP_GOAL_S,
               'wall_s_median': statistics.median(r['wall_s'] for r in runs) if runs else None,
               'failures': {}}
    print()
    print('| figure | value | goal |')
    print('| --- | --- | --- |')
    wall = [r['wall_s'] for r in runs]
    print('| whole demo run, wall time (n=%d, %d ok) | median %.1f s, max %.1f s | < %.0f s |'
          % (len(runs), len(ok_runs), statistics.median(wall), max(wall), RUN_GOAL_S))
    for key, d in per_failure.items():
        s = {k: ({'median': statistics.median(v), 'min': min(v), 'max': max(v), 'n': len(v), 'values': v}
                 if v else None) for k, v in d.items()}
        summary['failures'][key] = s
        g = s['display_gap_s']
        if g:
            print('| display gap, %s: last frame of the failed stream → substitute drawn (n=%d) | median %.2f s '
                  '(%.2f–%.2f) | ≤ %.1f s median |' % (key, g['n'], g['median'], g['min'], g['max'], GAP_GOAL_S))
        for k, text in (('detection_s', 'detection, unplug → first FAILED'),
                        ('propagation_s', 'propagation, FAILED → action'),
                        ('switch_s', 'switch, unplug → substitute drawn')):
            if s[k]:
                print('| %s, %s (n=%d) | median %.3f s | — |' % (text, key, s[k]['n'], s[k]['median']))
    summary['raw'] = runs
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'demo.json'), 'w') as f:
        json.dump(summary, f, indent=2, sort_keys=True, default=str)
    return 0 if ok_runs else 1


if __name__ == '__main__':
    sys.exit(main())
