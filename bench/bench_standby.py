#!/usr/bin/env python3
"""Standby policies side by side: the display gap of each (cold, warm, hot), what each costs, and flapping.

1. **Gaps.** ``temoto demo --standby P --replug`` as a user starts it, ``--rounds`` times per policy, the
   policies interleaved (the order turns each round, so that no policy always runs first on a warm page
   cache). Each run unplugs the D435 (crash), then the Hokuyo (stall), then plugs the D435 back. From each
   run's bag (its report.json): the display gap per failure (the failed stream's last frame to the
   substitute's first frame drawn in RViz) and, for the fail-back, the frames RViz drew with neither view.
2. **Cost.** The demo's stack, the first view on screen and the policy's spare ready (hot: its hidden
   display holding data); then every process of the stack but the bag recorder is measured for
   ``--cost-seconds``. The extra CPU of a policy is its total minus cold's, in % of one core, with the
   processes that account for it.
3. **Flapping.** The D435's cable toggles every 0.25 s (2 Hz) for ``--flap-seconds`` while the view is on
   it: the switches the operator sees, the tries the action makes, and the quarantine. Under the bound,
   the action switches away once and leaves the camera alone; the longest time the screen got no new
   frame across a switch is set beside the policy's gap goal.

Goals (the standby issue): display gap, hot <= 0.20 s median and <= 0.25 s p95; warm <= 0.45 s median;
cold <= 0.6 s median; fail-back under hot with no blank frame; the cost of each policy written beside it.

Prints markdown tables and writes bench/results/standby.json.
Usage: python bench/bench_standby.py [--rounds N] [--cost-rounds N] [--cost-seconds S] [--flap-seconds S]
       (internal: --probe cost|flap --standby P --out DIR runs one stack in this process)
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
from typing import Dict, List

import psutil

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from bench_demo import one_run  # noqa: E402
from common import child_env, cpu_percent_per_process, pct  # noqa: E402

POLICIES = ('cold', 'warm', 'hot')
GAP_GOALS = {'cold': {'median': 0.6}, 'warm': {'median': 0.45}, 'hot': {'median': 0.20, 'p95': 0.25}}
FAILURES = (('d435', 'crash'), ('hokuyo', 'stall'))
RECORDER = 'temoto_demo_record'
FLAP_DEVICE = 'd435'
FLAP_HALF_PERIOD = 0.25            # 2 Hz: unplugged 0.25 s, plugged 0.25 s
RESULT = 'RESULT '


# --------------------------------------------------------------------------------------------- probes
def process_label(proc: psutil.Process) -> str:
    """What a process is, for the cost table: its ROS node name, else its script or program."""
    try:
        argv = proc.cmdline()
    except psutil.Error:
        return '?'
    for arg in argv:
        if arg.startswith('__name:='):
            return arg.split(':=', 1)[1]
    if argv and 'python' in os.path.basename(argv[0]):
        if '-c' in argv:
            if any('multiprocessing' in a for a in argv):      # the simulation's render worker
                try:
                    return process_label(proc.parent()) + ' (worker)'
                except psutil.Error:
                    return 'worker'
            return proc.name()      # a fork of the ER Manager's zygote: its comm is the driver's script name
        rest = [a for a in argv[1:] if not a.startswith('-')]
        return os.path.basename(rest[0]) if rest else 'python'
    return os.path.basename(argv[0]) if argv else proc.name()


def measure_cost(seconds: float) -> dict:
    """CPU of every process under this one (the stack) but the recorder, per label, in % of one core."""
    procs = [p for p in psutil.Process().children(recursive=True) if process_label(p) != RECORDER]
    labels = {p.pid: process_label(p) for p in procs}
    per_pid = cpu_percent_per_process(procs, seconds)
    by_label: Dict[str, float] = {}
    for pid, value in per_pid.items():
        by_label[labels[pid]] = by_label.get(labels[pid], 0.0) + value
    return {'total': sum(per_pid.values()), 'by_label': by_label, 'seconds': seconds}


def flap(demo, seconds: float) -> dict:
    """Toggle the first view's cable at 2 Hz for ``seconds``; the action's events in that time."""
    since = time.monotonic()
    toggles = 0
    plugged = True
    # bounded in count and time: one toggle per half period
    for _ in range(int(seconds / FLAP_HALF_PERIOD)):
        plugged = not plugged
        demo.set_device(FLAP_DEVICE, plugged, 'crash')
        toggles += 1
        time.sleep(max(0.0, since + toggles * FLAP_HALF_PERIOD - time.monotonic()))   # the toggle's rhythm
    if not plugged:
        demo.set_device(FLAP_DEVICE, True)
    events = [dict(e, t=e['arrival'] - since) for e in demo.watcher.actions if e['arrival'] >= since]
    return {'toggles': toggles, 'seconds': time.monotonic() - since, 'events': events}


def switch_gaps(bag: str) -> List[float]:
    """For each view switch in ``bag``: the time the screen got no new frame, from the old stream's last
    message to the new view's first frame drawn (an upper bound: the old view may have drawn its last
    message later; a seamless switch still shows up to one period of the old stream)."""
    from temoto_demo.report import analyse, load_run
    run = load_run(bag)
    stages = analyse(run).stages
    gaps = []
    for old, new in zip(stages, stages[1:]):
        if new.first_frame_t is None:
            continue
        last = [t for t in run.ticks.get(old.topic, []) if t < new.first_frame_t]
        if last:
            gaps.append(new.first_frame_t - last[-1])
    return gaps


def reliability(namespace: str, sensor: str) -> float:
    from temoto_sensor_manager.interface import fetch_catalogue
    return next(float(r['reliability']) for r in fetch_catalogue(namespace, 2.0) if r['name'] == sensor)


def probe(kind: str, standby: str, out: str, seconds: float) -> int:
    """One stack in this process (rospy can join one master per process): the first view and its spare, then
    the cost window or the flapping; prints one RESULT line of JSON."""
    from temoto_demo.scenario import Demo, DemoOptions
    demo = Demo(DemoOptions(out_dir=out, standby=standby, report=False))
    result: dict = {'kind': kind, 'standby': standby}
    try:
        demo.start()
        demo.show_first_view()
        demo.wait_standby(1, demo.opts.stage_timeout)
        if kind == 'cost':
            result.update(measure_cost(seconds))
        else:
            started = time.monotonic() - demo.progress.t0
            before = reliability(demo.opts.namespace, 'realsense_d435')
            result.update(flap(demo, seconds))
            result['reliability'] = [before, reliability(demo.opts.namespace, 'realsense_d435')]
            result['started_s'] = started
    finally:
        leftovers = demo.stop()
    result['leftovers'] = len(leftovers)
    if kind == 'flap':
        result['switch_gaps'] = switch_gaps(demo.bag_path)
    print(RESULT + json.dumps(result, default=str), flush=True)
    return 0 if not leftovers else 1


def run_probe(kind: str, standby: str, out: str, seconds: float) -> dict:
    env = child_env()
    proc = subprocess.run([sys.executable, os.path.abspath(__file__), '--probe', kind, '--standby', standby,
                           '--out', out, '--seconds', str(seconds)], env=env, capture_output=True, text=True,
                          timeout=300 + seconds, cwd=ROOT)
    lines = [line for line in proc.stdout.splitlines() if line.startswith(RESULT)]
    if proc.returncode != 0 or not lines:
        return {'error': 'rc %d: %s' % (proc.returncode, (proc.stderr or proc.stdout)[-1500:])}
    return json.loads(lines[-1][len(RESULT):])


# --------------------------------------------------------------------------------------------- tables
def summary(values: List[float]) -> dict:
    return {'n': len(values), 'median': statistics.median(values), 'p95': pct(values, 95),
            'min': min(values), 'max': max(values), 'values': values} if values else {'n': 0}


def gap_text(s: dict) -> str:
    if not s.get('n'):
        return '-'
    return 'median %.3f s, p95 %.3f s (%.3f–%.3f, n=%d)' % (s['median'], s['p95'], s['min'], s['max'], s['n'])


def goal_text(policy: str) -> str:
    goal = GAP_GOALS[policy]
    return ' and '.join('≤ %.2f s %s' % (v, k) for k, v in goal.items())


def meets(policy: str, s: dict) -> bool:
    return bool(s.get('n')) and all(s[k] <= v for k, v in GAP_GOALS[policy].items())


def print_gaps(gaps: dict, failbacks: dict, walls: dict) -> None:
    print('| policy | failure | display gap: last frame of the failed stream → substitute drawn | goal | met |')
    print('| --- | --- | --- | --- | --- |')
    for policy in POLICIES:
        for device, mode in FAILURES:
            s = gaps[policy]['%s (%s)' % (device, mode)]
            print('| %s | %s (%s) | %s | %s | %s |' % (policy, device, mode, gap_text(s), goal_text(policy),
                                                       'yes' if meets(policy, s) else 'NO'))
    print()
    print('| policy | fail-back after the replug: frames drawn with neither view | replug → better view drawn | '
          'demo runs ok (wall time, median) | goal |')
    print('| --- | --- | --- | --- | --- |')
    for policy in POLICIES:
        fb = failbacks[policy]
        blank = [b for b in fb['blank_frames'] if b is not None]
        print('| %s | %s (n=%d) | %s | %d/%d (%.1f s) | %s |'
              % (policy, 'max %d, total %d' % (max(blank), sum(blank)) if blank else '-', len(blank),
                 'median %.2f s' % statistics.median(fb['delay_s']) if fb['delay_s'] else '-',
                 walls[policy]['ok'], walls[policy]['n'], statistics.median(walls[policy]['wall_s']),
                 '0 blank frames (hot)' if policy == 'hot' else '-'))


def print_cost(costs: dict) -> None:
    """The standby's own processes (those cold does not run), and the RViz host beside warm's: these machines
    have 2 cores and the stack fills them, so a new process takes CPU from the others and the stack's total
    says little; it is printed for the record."""
    cold, warm = costs.get('cold'), costs.get('warm')
    print()
    print('| policy | the standby driver\'s own processes | RViz host (hot: its hidden display; Δ over warm) | '
          'whole stack, recorder left out (2 cores: at most 200 %) | goal |')
    print('| --- | --- | --- | --- | --- |')
    for policy in POLICIES:
        c = costs.get(policy)
        if not c:
            print('| %s | - | - | - | - |' % policy)
            continue
        own = {k: v for k, v in c['by_label'].items() if cold is not None and k not in cold['by_label']}
        own_text = '%.0f %% of a core (%s)' % (sum(own.values()), ', '.join(
            '%s %.0f' % kv for kv in sorted(own.items(), key=lambda kv: -kv[1]))) if own else 'none'
        host = c['by_label'].get('rviz_host', 0.0)
        host_text = '%.0f %%' % host
        if policy == 'hot' and warm is not None:
            host_text += ' (%+.0f)' % (host - warm['by_label'].get('rviz_host', 0.0))
        print('| %s | %s | %s | %.0f %% (n=%d × %.0f s) | the cost written beside the gap |'
              % (policy, own_text, host_text, c['total'], c['n'], c['seconds']))


def print_flaps(flaps: dict) -> None:
    print()
    print('| policy | D435 toggled at 2 Hz for | switches seen | fail-back tries: all, started then flapped | quarantined after | '
          'longest screen without a new frame across a switch | D435 reliability before → after | bound |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- |')
    for policy, f in flaps.items():
        if 'error' in f:
            print('| %s | FAILED: %s | | | | | | |' % (policy, f['error'][-200:].replace('\n', ' ').replace('|', '/')))
            continue
        events = f['events']
        switches = [e for e in events if e.get('event') == 'sensor_active']
        abandoned = [e for e in events if e.get('event') == 'failback_abandoned']
        tries = [e for e in events if e.get('event') in ('failback_candidate', 'failback_unavailable')]
        quarantined = next((e for e in abandoned if e.get('quarantined')), None)
        longest = max(f['switch_gaps']) if f['switch_gaps'] else None
        goal = GAP_GOALS[policy]['median']
        print('| %s | %.0f s (%d toggles) | %d | %d, %d | %s | %s | %.3f → %.3f | ≤ 1 switch per backoff window; '
              'screen ≤ %.2f s without a frame |'
              % (policy, f['seconds'], f['toggles'], len(switches), len(tries), len(abandoned),
                 '%.1f s (%d tries)' % (quarantined['t'], abandoned.index(quarantined) + 1) if quarantined else 'no',
                 '-' if longest is None else '%.3f s' % longest, f['reliability'][0], f['reliability'][1], goal))


# --------------------------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--rounds', type=int, default=10, help='demo runs per policy (each: a crash and a stall)')
    ap.add_argument('--cost-rounds', type=int, default=2)
    ap.add_argument('--cost-seconds', type=float, default=10.0)
    ap.add_argument('--flap-seconds', type=float, default=60.0)
    ap.add_argument('--flap-policies', default='cold,hot')
    ap.add_argument('--keep', default='', help='keep the run folders here')
    ap.add_argument('--probe', choices=('cost', 'flap'), help=argparse.SUPPRESS)
    ap.add_argument('--standby', choices=POLICIES, help=argparse.SUPPRESS)
    ap.add_argument('--out', help=argparse.SUPPRESS)
    ap.add_argument('--seconds', type=float, help=argparse.SUPPRESS)
    opts = ap.parse_args(argv)
    if opts.probe:
        return probe(opts.probe, opts.standby, opts.out, opts.seconds)

    base = opts.keep or tempfile.mkdtemp(prefix='bench_standby_')
    gaps = {p: {'%s (%s)' % f: [] for f in FAILURES} for p in POLICIES}
    failbacks = {p: {'blank_frames': [], 'delay_s': []} for p in POLICIES}
    walls = {p: {'n': 0, 'ok': 0, 'wall_s': []} for p in POLICIES}
    errors = []
    for r in range(opts.rounds):
        order = POLICIES[r % 3:] + POLICIES[:r % 3]
        for policy in order:
            run = one_run(os.path.join(base, 'gap_%s_%02d' % (policy, r)), ['--standby', policy, '--replug'])
            walls[policy]['n'] += 1
            walls[policy]['ok'] += run['rc'] == 0
            walls[policy]['wall_s'].append(run['wall_s'])
            if run['rc'] != 0:
                errors.append('%s round %d: rc %d %s' % (policy, r, run['rc'], run.get('error', '')[-300:]))
            for f in run['failures']:
                key = '%s (%s)' % (f['device'], f['mode'])
                if key in gaps[policy] and f.get('display_gap_s') is not None:
                    gaps[policy][key].append(f['display_gap_s'])
            for fb in run['failbacks']:
                failbacks[policy]['blank_frames'].append(fb.get('blank_frames'))
                if fb.get('delay_s') is not None:
                    failbacks[policy]['delay_s'].append(fb['delay_s'])
            print('  round %d/%d %s: rc %d, %.1f s; gaps %s; fail-back blank frames %s'
                  % (r + 1, opts.rounds, policy, run['rc'], run['wall_s'],
                     ', '.join('%s %.3f s' % (f['device'], f['display_gap_s']) for f in run['failures']
                               if f.get('display_gap_s') is not None) or '-',
                     [fb.get('blank_frames') for fb in run['failbacks']]), flush=True)

    costs_raw: Dict[str, List[dict]] = {p: [] for p in POLICIES}
    for r in range(opts.cost_rounds):
        for policy in POLICIES[r % 3:] + POLICIES[:r % 3]:
            c = run_probe('cost', policy, os.path.join(base, 'cost_%s_%02d' % (policy, r)), opts.cost_seconds)
            if 'error' in c:
                errors.append('cost %s: %s' % (policy, c['error'][-300:]))
                continue
            costs_raw[policy].append(c)
            print('  cost %s: %.0f %% of a core' % (policy, c['total']), flush=True)
    costs = {}
    for policy, runs in costs_raw.items():
        if runs:
            labels = {k for c in runs for k in c['by_label']}
            costs[policy] = {'total': statistics.mean(c['total'] for c in runs), 'n': len(runs),
                             'seconds': opts.cost_seconds,
                             'by_label': {k: statistics.mean(c['by_label'].get(k, 0.0) for c in runs) for k in labels}}

    flaps = {}
    for policy in [p for p in opts.flap_policies.split(',') if p]:
        flaps[policy] = run_probe('flap', policy, os.path.join(base, 'flap_%s' % policy), opts.flap_seconds)
        if 'error' in flaps[policy]:
            errors.append('flap %s: %s' % (policy, flaps[policy]['error'][-300:]))
        else:
            print('  flap %s: %d switches' % (policy, sum(e.get('event') == 'sensor_active'
                                                           for e in flaps[policy]['events'])), flush=True)
    if not opts.keep:
        shutil.rmtree(base, ignore_errors=True)

    summaries = {p: {k: summary(v) for k, v in gaps[p].items()} for p in POLICIES}
    print()
    print_gaps(summaries, failbacks, walls)
    print_cost(costs)
    print_flaps(flaps)
    for error in errors:
        print('problem: %s' % error.replace('\n', ' '))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'standby.json'), 'w') as f:
        json.dump({'gaps': summaries, 'failbacks': failbacks, 'walls': walls, 'costs': costs, 'costs_raw': costs_raw,
                   'flaps': flaps, 'goals': GAP_GOALS, 'errors': errors}, f, indent=2, sort_keys=True, default=str)
    return 0 if not errors else 1


if __name__ == '__main__':
    sys.exit(main())
