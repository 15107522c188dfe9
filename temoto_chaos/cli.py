"""``temoto chaos --seed S --steps N [--until STEP] [--clients K] [--hosts 2] [--history V] [--out DIR]``."""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from typing import List, Optional

from temoto_core.hosts import unavailable

from .history import CLIENT_OPS, CLIENTS, CONCURRENT_FROM, VERSION
from .runner import ChaosOptions, run_chaos

DEFAULT_STEPS = 300


def chaos_options(argv: Optional[List[str]] = None) -> ChaosOptions:
    """The run that ``argv`` asks for; a bad argument exits with argparse's error, naming it."""
    p = argparse.ArgumentParser(prog='temoto chaos', description='Run a seeded history of client operations and '
                                'faults against the robot\'s managers, checking the invariants as it goes.')
    p.add_argument('--seed', type=int, required=True)
    p.add_argument('--steps', type=int, default=None,
                   help='how many steps (default: %d, or all those before --until)' % DEFAULT_STEPS)
    p.add_argument('--until', type=int, default=None, help='replay only the steps before this one')
    p.add_argument('--clients', type=int, default=None,
                   help='how many clients (default: the history version\'s, %s)'
                        % ', '.join('%d for %d' % (n, v) for v, n in sorted(CLIENTS.items())))
    p.add_argument('--serial', action='store_true',
                   help='one step at a time (from history %d the clients work concurrently by default)'
                        % CONCURRENT_FROM)
    p.add_argument('--settle', type=float, default=20.0, help='seconds a step gets to settle before a violation')
    p.add_argument('--hosts', type=int, choices=(1, 2), default=1,
                   help='2: the robot on one host and the clients on the station (network namespaces; needs root), '
                        'with the link cut and healed as a fault')
    p.add_argument('--history', type=int, default=VERSION, choices=sorted(CLIENT_OPS),
                   help='how steps are drawn from the seed (%d: the latest; older versions replay older reports)'
                        % VERSION)
    p.add_argument('--out', default='', help='run folder (logs, chaos.json); default: a new temporary one')
    args = p.parse_args(argv)
    if args.clients is None:
        args.clients = CLIENTS[args.history]
    if args.steps is None:
        # a failure's replay command names its step, not the run's length: --until alone replays up to it
        args.steps = DEFAULT_STEPS if args.until is None else args.until
    if args.steps < 1 or args.clients < 1 or args.settle <= 0 or (args.until is not None and args.until < 1):
        p.error('--steps, --clients, --until and --settle must be positive')
    return ChaosOptions(seed=args.seed, steps=args.steps, out_dir=args.out, clients=args.clients,
                        settle_s=args.settle, until=args.until, hosts=args.hosts, version=args.history,
                        serial=args.serial)


def chaos_main(argv: Optional[List[str]] = None) -> int:
    opts = chaos_options(argv)
    if opts.hosts == 2:
        why = unavailable()
        if why:
            print('temoto chaos --hosts 2: %s' % why, file=sys.stderr)
            return 2
    opts.out_dir = os.path.abspath(opts.out_dir or tempfile.mkdtemp(prefix='temoto_chaos_'))
    concurrently = opts.version >= CONCURRENT_FROM and not opts.serial
    last = opts.steps if opts.until is None else min(opts.steps, opts.until)
    print('temoto chaos: seed %d, %d steps, %d clients%s; run folder %s'
          % (opts.seed, last, opts.clients, ' working concurrently' if concurrently else '', opts.out_dir),
          flush=True)
    return run_chaos(opts)


if __name__ == '__main__':
    sys.exit(chaos_main())
