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


def chaos_main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog='temoto chaos', description='Run a seeded history of client operations and '
                                'faults against the robot\'s managers, checking the invariants after every step.')
    p.add_argument('--seed', type=int, required=True)
    p.add_argument('--steps', type=int, default=300)
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
    if args.steps < 1 or args.clients < 1 or args.settle <= 0 or (args.until is not None and args.until < 1):
        p.error('--steps, --clients, --until and --settle must be positive')
    if args.hosts == 2:
        why = unavailable()
        if why:
            print('temoto chaos --hosts 2: %s' % why, file=sys.stderr)
            return 2
    out = os.path.abspath(args.out or tempfile.mkdtemp(prefix='temoto_chaos_'))
    concurrently = args.history >= CONCURRENT_FROM and not args.serial
    print('temoto chaos: seed %d, %d steps, %d clients%s; run folder %s'
          % (args.seed, args.steps, args.clients, ' working concurrently' if concurrently else '', out), flush=True)
    return run_chaos(ChaosOptions(seed=args.seed, steps=args.steps, out_dir=out, clients=args.clients,
                                  settle_s=args.settle, until=args.until, hosts=args.hosts,
                                  version=args.history, serial=args.serial))


if __name__ == '__main__':
    sys.exit(chaos_main())
