#!/usr/bin/env python3
"""A child started with code between fork and exec, beside imports and log calls: wedged runs, before and after.

Each run is a fresh process with four kinds of threads, as a manager has them: one imports modules it has
not seen yet, two make log calls (``logging.getLogger`` on every call, as rospy does), one makes and drops
log handlers (freed by the garbage collector, at any moment, in any thread), and one starts children that
must die with it (a ``preexec_fn`` between fork and exec):

- **before**: ``subprocess.Popen(..., preexec_fn=...)``, as the ER Manager's supervisor and the RViz host's
  Xvfb did. The fork's before-fork hooks take logging's lock, then the import lock, the other way round
  from an import whose garbage collection needs logging's lock;
- **after**: ``temoto_core.process_group.popen_dying_with_this_thread``, which takes the import lock first.

A run is wedged when no thread makes progress for 8 s; its threads' stacks are kept in the results. The
kinds alternate, so that neither always runs on a cold page cache.

Goal: no wedged run after (it was the ER Manager's wedge in the chaos history, seed 17).
Prints a markdown table; writes bench/results/fork_locks.json.
Usage: python bench/bench_fork_locks.py [--rounds N] [--seconds S]
       (internal: --run before|after --seconds S --modules DIR)
"""
import argparse
import faulthandler
import importlib
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from temoto_core.process_group import popen_dying_with_this_thread  # noqa: E402

MODULES = 6000
STALL_S = 8.0


def write_modules(directory: str) -> None:
    for i in range(MODULES):
        with open(os.path.join(directory, 'forklock_m%d.py' % i), 'w') as f:
            f.write("import logging\nlog = logging.getLogger('forklock%d')\n"
                    "class Cycle:\n    def __init__(self):\n        self.me = self\n"
                    "garbage = [Cycle() for _ in range(50)]\n" % i)


def run(kind: str, seconds: float, modules: str) -> int:
    """One run in this process: 0 if every thread made progress throughout, 3 if it wedged."""
    sys.path.insert(0, modules)
    logging.basicConfig(stream=open(os.devnull, 'w'), level=logging.INFO)
    progress = {'imports': 0, 'logs': 0, 'starts': 0, 'handlers': 0}
    stop = threading.Event()

    def importer():
        for i in range(MODULES):
            if stop.is_set():
                return
            importlib.import_module('forklock_m%d' % i)
            progress['imports'] += 1

    def logger():
        while not stop.is_set():
            logging.getLogger('rosout').info('message %d', progress['logs'])
            progress['logs'] += 1

    def handlers():
        while not stop.is_set():
            handler = logging.StreamHandler(open(os.devnull, 'w'))
            handler.cycle = handler           # freed by the cyclic collector only, in whichever thread runs it
            del handler
            progress['handlers'] += 1

    def starter():
        while not stop.is_set():
            if kind == 'before':
                child = subprocess.Popen(['true'], preexec_fn=lambda: None)
            else:
                child = popen_dying_with_this_thread(['true'], 9)
            child.wait()
            progress['starts'] += 1

    threads = [threading.Thread(target=f, daemon=True) for f in (importer, logger, logger, handlers, starter)]
    for t in threads:
        t.start()
    last, since = None, time.monotonic()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and threads[0].is_alive():
        stop.wait(0.5)                        # the monitor's own pace: this run's clock, not a synchronisation
        now = dict(progress)
        if now != last:
            last, since = now, time.monotonic()
        elif time.monotonic() - since > STALL_S:
            print(json.dumps({'wedged': True, 'progress': now}), flush=True)
            faulthandler.dump_traceback(all_threads=True)
            os._exit(3)
    print(json.dumps({'wedged': False, 'progress': dict(progress)}), flush=True)
    os._exit(0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n', 1)[0])
    parser.add_argument('--rounds', type=int, default=4)
    parser.add_argument('--seconds', type=float, default=30.0)
    parser.add_argument('--run', choices=('before', 'after'))
    parser.add_argument('--modules')
    opts = parser.parse_args()
    if opts.run:
        return run(opts.run, opts.seconds, opts.modules)
    results = {'before': [], 'after': []}
    stacks = {}
    for round_ in range(opts.rounds):
        for kind in (('before', 'after') if round_ % 2 == 0 else ('after', 'before')):
            modules = tempfile.mkdtemp(prefix='bench_fork_locks_')
            try:
                write_modules(modules)
                t0 = time.monotonic()
                out = subprocess.run([sys.executable, __file__, '--run', kind, '--seconds', str(opts.seconds),
                                      '--modules', modules], capture_output=True, text=True,
                                     timeout=opts.seconds + 60)
            finally:
                shutil.rmtree(modules, ignore_errors=True)
            wedged = out.returncode == 3
            results[kind].append({'wedged': wedged, 'seconds': round(time.monotonic() - t0, 1),
                                  'progress': json.loads(out.stdout.splitlines()[0])['progress']})
            if wedged and kind not in stacks:
                stacks[kind] = out.stderr[-6000:]
            print('  %s round %d: %s' % (kind, round_ + 1, 'WEDGED' if wedged else 'ok'), file=sys.stderr,
                  flush=True)
    print('| starts of a child with code between fork and exec, beside imports and log calls | runs | wedged | goal |')
    print('| --- | --- | --- | --- |')
    for kind, label in (('before', 'before: `Popen(preexec_fn=...)`'),
                        ('after', 'after: `popen_dying_with_this_thread` (the import lock first)')):
        runs = results[kind]
        print('| %s | %d (up to %.0f s each) | **%d** | %s |' % (label, len(runs), opts.seconds,
                                                                sum(r['wedged'] for r in runs),
                                                                '0' if kind == 'after' else '-'))
    os.makedirs(os.path.join(ROOT, 'bench', 'results'), exist_ok=True)
    with open(os.path.join(ROOT, 'bench', 'results', 'fork_locks.json'), 'w') as f:
        json.dump({'runs': results, 'stacks': stacks, 'seconds': opts.seconds}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
