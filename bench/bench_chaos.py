#!/usr/bin/env python3
"""Chaos: a long seeded history of client operations and faults against the robot's managers, checked after
every step (``temoto chaos``, docs/chaos.md).

Goals (issue: proof under chaos): 10,000 steps over two hosts with every kind of fault and 0 violations,
within 30 minutes (1,800 s: 5.56 steps per second), the checker's share beside it. From history 5 the clients
hold motion too, and each stop case's worst time from the fault to the part at rest (the simulation's ground
truth) is printed beside its bound. ``make bench`` runs exactly that (the defaults); ``--steps`` and
``--hosts 1`` run less. Besides the summary, the time of the run is split by kind of step (doing it, then
checking until the system settled), which says where the throughput goes.

Prints a markdown table and writes bench/results/chaos.json.
Usage: python bench/bench_chaos.py [--steps N] [--seed S] [--hosts 1|2] [--serial | --compare]
"""
import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from common import child_env  # noqa: E402
from temoto_chaos.runner import CLIENT_STEPS  # noqa: E402
GOAL_STEPS_PER_S = 10000 / 1800.0
PROGRESS_EVERY = 500          # steps between progress lines


def run(opts, out: str) -> int:
    """The history, its progress shown every PROGRESS_EVERY steps; bounded by 5 s a step and 10 minutes."""
    cmd = [sys.executable, '-m', 'temoto_bringup.cli', 'chaos', '--seed', str(opts.seed), '--steps', str(opts.steps),
           '--hosts', str(opts.hosts), '--out', out] + (['--serial'] if opts.serial else [])
    deadline = time.monotonic() + opts.steps * 5 + 600
    with open(os.path.join(out, 'stdout.log'), 'w') as log:
        proc = subprocess.Popen(cmd, env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                cwd=ROOT)
        for line in proc.stdout:
            log.write(line)
            if line.startswith('[step ') and int(line[6:line.index(']')]) % PROGRESS_EVERY == 0:
                print('  %s' % line.strip()[:100], file=sys.stderr, flush=True)
            if time.monotonic() > deadline:
                proc.terminate()      # the run stops cleanly and still writes what it did (summary 'interrupted')
                break
        return proc.wait()


def by_kind(log: list) -> dict:
    """kind -> [steps, the runner's seconds doing them (queueing a client's call included), its seconds
    checking after them, the clients' seconds in the calls (concurrent histories: beside the runner)]."""
    out = collections.defaultdict(lambda: [0, 0.0, 0.0, 0.0])
    for e in log:
        row = out[e['kind']]
        row[0] += 1
        row[1] += e.get('apply_s', 0.0)
        row[2] += e.get('check_s', 0.0)
        row[3] += e.get('call_s', 0.0)
    return dict(out)


def waited_for(log: list, top: int = 5) -> list:
    """What the checks waited for most (a transient state, before it settled): [(what, steps, seconds)]."""
    seen = collections.defaultdict(lambda: [0, 0.0])
    for e in log:
        if e.get('waited_for'):
            what = re.sub(r'\d+', 'N', e['waited_for'])[:100]
            seen[what][0] += 1
            seen[what][1] += e.get('check_s', 0.0)
    return sorted(((w, n, t) for w, (n, t) in seen.items()), key=lambda row: -row[2])[:top]


def motion_tables(motion) -> None:
    """History 5: what the clients moved, and per stop case the worst time from the fault to the part at rest
    (the simulation's ground truth) beside its bound."""
    if not motion:
        return
    counts = motion.get('counts', {})
    print()
    print('| motion (history 5; the simulation\'s ground truth) | value | goal |')
    print('| --- | --- | --- |')
    print('| motion goals sent: drives, servo streams, gripper goals | %d, %d, %d | - |' % (
        counts.get('goals goal', 0), counts.get('goals servo', 0), counts.get('goals grip', 0)))
    print('| refused at once (a bad goal): drives, gripper goals | %d, %d (each moved nothing) | - |' % (
        counts.get('refused goal', 0), counts.get('refused grip', 0)))
    ended = sorted((k[len('ended '):], v) for k, v in counts.items() if k.startswith('ended '))
    print('| how motion goals ended | %s | each with a reason |' % ', '.join('%s %d' % kv for kv in ended))
    print('| motion with no live holder (beyond the stop allowance) | %.3f s | 0 |'
          % motion.get('worst_uncovered_s', 0.0))
    print('| contacts; blind drives (the base moving with no fresh obstacle source) | %d; %d | 0; 0 |' % (
        counts.get('contacts', 0), counts.get('blind drives', 0)))
    print()
    print('| stop case / part | faults while it moved: measured | worst fault → at rest | bound (the widest) | '
          'worst share of its own bound | at rest already | a new goal or another holder moved it on |')
    print('| --- | --- | --- | --- | --- | --- | --- |')
    for key, row in sorted(motion.get('stop_cases', {}).items()):
        measured = row['measured']
        print('| %s | %d | %s | %.3f s | %s | %d | %d |' % (
            key.replace('_', ' '), measured, '%.3f s' % row['worst_s'] if measured else '-', row['bound_s'],
            '%.0f %%' % (100 * row.get('worst_of_bound', 0.0)) if measured else '-', row['was_at_rest'],
            row['restarted'] + row['held']))


def percentile(values: list, q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))] if values else 0.0


def compare(opts) -> int:
    """The same first steps of the seed one step at a time, then with the clients concurrent, side by side."""
    rows, rc = [], 0
    for serial in (True, False):
        opts.serial = serial
        out = tempfile.mkdtemp(prefix='bench_chaos_')
        rc = run(opts, out) or rc
        with open(os.path.join(out, 'chaos.json')) as f:
            result = json.load(f)
        summary = result['summary']
        # the runner's time per step, and per client call the time from its step to its answer
        runner = [e.get('apply_s', 0.0) + e.get('check_s', 0.0) for e in result['log']]
        calls = [e['call_s'] for e in result['log'] if 'call_s' in e]
        rows.append(('one step at a time' if serial else 'clients concurrent', summary, runner, calls))
    print('| seed %d, %d steps, %d host(s) | steps/s | runner per step: median (p95) | violations | checks |'
          % (opts.seed, opts.steps, opts.hosts))
    print('| --- | --- | --- | --- | --- |')
    for label, summary, runner, _ in rows:
        print('| %s | %.2f | %.3f s (%.3f s) | %d | %d |' % (label, summary.get('steps_per_s', 0.0),
                                                          percentile(runner, 0.5), percentile(runner, 0.95),
                                                          len(summary.get('violations', [])), summary.get('checks', 0)))
    ratio = rows[1][1].get('steps_per_s', 0.0) / max(rows[0][1].get('steps_per_s', 0.0), 1e-9)
    print('\nconcurrent / serial throughput: %.2fx (goal: >= %.2f steps/s)' % (ratio, GOAL_STEPS_PER_S))
    return rc


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--steps', type=int, default=10000)
    ap.add_argument('--seed', type=int, default=17)
    ap.add_argument('--hosts', type=int, choices=(1, 2), default=2)
    ap.add_argument('--serial', action='store_true', help='one step at a time (the clients not concurrently)')
    ap.add_argument('--compare', action='store_true',
                    help='run the steps one at a time, then concurrently, and print the two side by side')
    opts = ap.parse_args(argv)
    if opts.compare:
        return compare(opts)
    out = tempfile.mkdtemp(prefix='bench_chaos_')
    rc = run(opts, out)
    with open(os.path.join(out, 'chaos.json')) as f:
        result = json.load(f)
    summary, kinds = result['summary'], by_kind(result['log'])
    faults = summary.get('faults', {})
    print('| figure | value | goal |')
    print('| --- | --- | --- |')
    print('| steps run (seed %d, %d host%s, history %s) | %d of %d%s | all |' % (
        opts.seed, opts.hosts, 's' if opts.hosts > 1 else '', summary.get('history', '?'), summary.get('steps', 0),
        opts.steps, ' (interrupted)' if summary.get('interrupted') else ''))
    print('| faults injected, by kind | %s (%d) | every kind |' % (
        ', '.join('%s %d' % kv for kv in sorted(faults.items())), sum(faults.values())))
    print('| invariant checks made (each reads every registry, every client and the process table) | %d | - |'
          % summary.get('checks', 0))
    print('| violations | %d%s | 0 |' % (len(summary.get('violations', [])), (': step %s: %s' % (
        summary.get('failed_step'), '; '.join(summary['violations'])[:300])) if summary.get('violations') else ''))
    print('| throughput | %.2f steps/s (%.0f s) | ≥ %.2f steps/s (10,000 steps in 30 min) |'
          % (summary.get('steps_per_s', 0.0), summary.get('seconds', 0.0), GOAL_STEPS_PER_S))
    print('| the checker\'s share of that time (reading every registry, client and process; the motion ledger) | '
          '%.0f s, %.0f %% (motion: %.1f s) | - |' % (
              summary.get('check_seconds', 0.0),
              100.0 * summary.get('check_seconds', 0.0) / max(summary.get('seconds', 0.0), 1e-9),
              summary.get('motion_check_seconds', 0.0)))
    print('| processes left behind | %d | 0 |' % summary.get('leftovers', -1))
    during = [e['kind'] in CLIENT_STEPS for e in result['log'] if 'during' in e]
    print('| steps while a fault lasted (checked once it ended): clients\' steps queued, faults | %d, %d | - |'
          % (during.count(True), during.count(False)))
    motion_tables(summary.get('motion'))
    print()
    print('| kind of step | steps | runner doing it: total (mean) | checking after it: total (mean) | '
          'the client\'s call: mean |')
    print('| --- | --- | --- | --- | --- |')
    for kind, (n, doing, checking, calling) in sorted(kinds.items(), key=lambda kv: -(kv[1][1] + kv[1][2])):
        print('| %s | %d | %.0f s (%.3f s) | %.0f s (%.3f s) | %s |' % (
            kind, n, doing, doing / n, checking, checking / n, '%.3f s' % (calling / n) if calling else '-'))
    print()
    print('| what the checks waited for most | steps | seconds |')
    print('| --- | --- | --- |')
    for what, n, seconds in waited_for(result['log']):
        print('| %s | %d | %.0f |' % (what.replace('|', '/'), n, seconds))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'chaos.json'), 'w') as f:
        json.dump(dict(summary, seed=opts.seed, requested=opts.steps, by_kind=kinds), f, indent=1, sort_keys=True)
    return rc


if __name__ == '__main__':
    sys.exit(main())
