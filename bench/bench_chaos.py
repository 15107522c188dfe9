#!/usr/bin/env python3
"""Chaos: a long seeded history of client operations and faults against the robot's managers, checked after
every step (``temoto chaos``, docs/chaos.md).

Goals (issue: proof under chaos): 0 violations; 10,000 steps within 30 minutes (5.6 steps per second).
The default is 2,000 steps: at the rate measured so far (about 1.4 steps per second, most of it the
managers' recoveries after a kill), 10,000 would take two hours; ``--steps 10000`` runs them.

Prints a markdown table and writes bench/results/chaos.json.
Usage: python bench/bench_chaos.py [--steps N] [--seed S]
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from common import child_env  # noqa: E402
GOAL_STEPS_PER_S = 10000 / 1800.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--steps', type=int, default=2000)
    ap.add_argument('--seed', type=int, default=17)
    opts = ap.parse_args(argv)
    out = tempfile.mkdtemp(prefix='bench_chaos_')
    env = child_env()
    proc = subprocess.run([sys.executable, '-m', 'temoto_core.cli', 'chaos', '--seed', str(opts.seed), '--steps',
                           str(opts.steps), '--out', out], env=env, capture_output=True, text=True, cwd=ROOT,
                          timeout=opts.steps * 5 + 600)
    with open(os.path.join(out, 'chaos.json')) as f:
        summary = json.load(f)['summary']
    faults = summary.get('faults', {})
    print('| figure | value | goal |')
    print('| --- | --- | --- |')
    print('| steps run (seed %d) | %d of %d | all |' % (opts.seed, summary.get('steps', 0), opts.steps))
    print('| faults injected, by kind | %s (%d) | every kind |' % (
        ', '.join('%s %d' % kv for kv in sorted(faults.items())), sum(faults.values())))
    print('| invariant checks made (each reads every registry, every client and the process table) | %d | - |'
          % summary.get('checks', 0))
    print('| violations | %d%s | 0 |' % (len(summary.get('violations', [])), (': step %s: %s' % (
        summary.get('failed_step'), '; '.join(summary['violations'])[:300])) if summary.get('violations') else ''))
    print('| throughput | %.2f steps/s (%.0f s) | ≥ %.1f steps/s (10,000 steps in 30 min) |'
          % (summary.get('steps_per_s', 0.0), summary.get('seconds', 0.0), GOAL_STEPS_PER_S))
    print('| processes left behind | %d | 0 |' % summary.get('leftovers', -1))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'chaos.json'), 'w') as f:
        json.dump(dict(summary, seed=opts.seed, requested=opts.steps), f, indent=1, sort_keys=True)
    return proc.returncode


if __name__ == '__main__':
    sys.exit(main())
