"""``temoto demo``, ``temoto record``, ``temoto report``.

    temoto demo teleop [--live] [--voice | --hosts 2] [--stage-timeout S] [--out runs/<timestamp>]
    temoto demo [--live] [--stage-timeout S] [--d435-mode crash|stall] [--hokuyo-mode crash|stall]
                [--priority rgbd,arm_cloud,base_scan] [--kill-managers [--seed N]] [--hosts 2 [--robot NS]]
                [--out runs/<timestamp>]
    temoto record [--out PATH] [--ns NS]      (against the running master, until Ctrl-C)
    temoto report BAG [--out DIR]
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from typing import List, Optional

from temoto_core.hosts import unavailable
from temoto_core.node import on_signals
from temoto_core.rr.messages import legal_name

from . import topics as T


def _print_report(rep) -> None:
    for f in rep.analysis.failures:
        def s(x):
            return '-' if x is None else '%.3f s' % x
        print('  %s (%s): detection %s, propagation %s, display gap %s, switch %s'
              % (f.device, f.mode, s(f.detection), s(f.propagation), s(f.display_gap), s(f.switch)))
    print('report: %s' % rep.path)


def report_main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog='temoto report', description='Make the report of a recorded run from its bag.')
    p.add_argument('bag', help='a bag recorded by temoto demo or temoto record')
    p.add_argument('--out', default='', help='folder for report.md and its images (default: beside the bag)')
    p.add_argument('--ns', '--namespace', dest='ns', default=T.DEFAULT_NS,
                   help='TeMoto namespace of the run (default: %(default)s)')
    args = p.parse_args(argv)
    if not os.path.isfile(args.bag):
        print('temoto report: no bag file at %s' % args.bag, file=sys.stderr)
        return 1
    from .report import write_report        # lazy: each subcommand loads only its own stack (matplotlib here)
    try:
        rep = write_report(args.bag, args.out or None, args.ns)
    except Exception as e:          # a corrupt or foreign bag: say which and why
        print('temoto report: cannot read %s: %s: %s' % (args.bag, type(e).__name__, e), file=sys.stderr)
        return 1
    _print_report(rep)
    return 0


RUNS_DIR = 'runs'


def default_run_dir() -> str:
    """``runs/<timestamp>``; ``runs`` gets a CATKIN_IGNORE first.

    The folder usually sits in the repository, which is on ROS_PACKAGE_PATH, and rospack would otherwise walk
    every old run on every package lookup (each node start, rosrun and roslaunch).
    """
    os.makedirs(RUNS_DIR, exist_ok=True)
    marker = os.path.join(RUNS_DIR, 'CATKIN_IGNORE')
    if not os.path.exists(marker):
        open(marker, 'w').close()
    return os.path.join(RUNS_DIR, time.strftime('%Y%m%d_%H%M%S'))


def record_main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog='temoto record', description='Record the failover topic set until Ctrl-C.')
    p.add_argument('--out', default='', help='bag path (default: runs/<timestamp>/failover.bag)')
    p.add_argument('--ns', '--namespace', dest='ns', default=T.DEFAULT_NS,
                   help='TeMoto namespace (default: %(default)s)')
    args = p.parse_args(argv)
    out = args.out or os.path.join(default_run_dir(), 'failover.bag')
    if os.path.isdir(out):
        out = os.path.join(out, 'failover.bag')
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    from .recording import Recording        # lazy: each subcommand loads only its own stack
    env = dict(os.environ)
    stop = threading.Event()
    on_signals(lambda signum: stop.set())     # from a thread: Event.set in a handler can deadlock
    rec = Recording(out, env, args.ns)
    try:
        rec.start()
        print('recording to %s (Ctrl-C to stop)' % out, flush=True)
        while not stop.wait(1.0):
            if rec.recorder is None or not rec.recorder.alive():
                print('temoto record: the recorder exited:\n%s' % rec.recorder.log(), file=sys.stderr)
                return 1
    except (RuntimeError, TimeoutError, OSError) as e:
        print('temoto record: %s' % e, file=sys.stderr)
        return 1
    finally:
        try:
            path = rec.stop()
            print('bag closed: %s' % path)
        except RuntimeError as e:
            print('temoto record: %s' % e, file=sys.stderr)
    return 0


def _no_two_hosts(p: argparse.ArgumentParser, args, prog: str) -> bool:
    """``--hosts 2`` asked for and not possible here (said why), or refused with ``--voice``."""
    if args.voice and args.hosts == 2:
        p.error('--voice runs on one host; --hosts 2 does not take it yet')
    why = unavailable() if args.hosts == 2 else ''
    if why:
        print('%s --hosts 2: %s' % (prog, why), file=sys.stderr)
    return bool(why)


def teleop_main(argv: Optional[List[str]] = None) -> int:
    from .scenario import DemoOptions               # lazy: rospy, RViz clients, the recorder
    from .teleop import run_teleop
    p = argparse.ArgumentParser(prog='temoto demo teleop', description='The operator moves the robot: a goal '
                                'pointed in RViz, "robot please go", the SICK unplugged on the way, the arm '
                                'following the hand, the gripper, the arm\'s controller crashing; recorded.')
    p.add_argument('--live', action='store_true', help='show RViz on $DISPLAY (default: headless under Xvfb)')
    p.add_argument('--voice', action='store_true', help='say the instructions (espeak-ng) to the speech node')
    p.add_argument('--stage-timeout', type=float, default=30.0, help='seconds each stage may take (default 30)')
    p.add_argument('--out', default='', help='run folder (default: runs/<timestamp>)')
    p.add_argument('--no-report', action='store_true', help='skip the report')
    p.add_argument('--hosts', type=int, choices=(1, 2), default=1,
                   help='2: the robot and the operator\'s station on two hosts (network namespaces; needs root); the '
                   'link is cut while the arm follows the hand')
    args = p.parse_args(argv)
    if args.stage_timeout <= 0:
        p.error('--stage-timeout must be positive')
    if args.live and not os.environ.get('DISPLAY'):
        p.error('--live needs a DISPLAY')
    if _no_two_hosts(p, args, 'temoto demo teleop'):
        return 2
    out = args.out or default_run_dir()
    return run_teleop(DemoOptions(out_dir=os.path.abspath(out), live=args.live, stage_timeout=args.stage_timeout,
                                  report=not args.no_report, voice=args.voice, hosts=args.hosts))


def demo_main(argv: Optional[List[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ['teleop']:
        return teleop_main(argv[1:])
    from .scenario import DemoOptions, PRIORITY_ENTRIES, run_demo     # lazy: rospy, RViz clients, the recorder
    p = argparse.ArgumentParser(prog='temoto demo', description='The paper\'s section 4: sensor failover, recorded.')
    p.add_argument('--live', action='store_true', help='show RViz on $DISPLAY (default: headless under Xvfb)')
    p.add_argument('--stage-timeout', type=float, default=30.0, help='seconds each stage may take (default 30)')
    p.add_argument('--d435-mode', choices=('crash', 'stall'), default='crash')
    p.add_argument('--hokuyo-mode', choices=('crash', 'stall'), default='stall')
    p.add_argument('--priority', default=','.join(PRIORITY_ENTRIES),
                   help='the view\'s sensor priority, best first, from: %s (default: %%(default)s)'
                   % ', '.join(PRIORITY_ENTRIES))
    p.add_argument('--out', default='', help='run folder (default: runs/<timestamp>)')
    p.add_argument('--no-report', action='store_true', help='skip the report')
    p.add_argument('--kill-managers', action='store_true',
                   help='run with recovery on, and SIGKILL each manager once while the first view is up')
    p.add_argument('--seed', type=int, default=0, help='--kill-managers: the order and moments (default 0)')
    p.add_argument('--hosts', type=int, choices=(1, 2), default=1,
                   help='2: the robot and the operator\'s station on two hosts (network namespaces; needs root)')
    p.add_argument('--robot', default='vaultbot', help='--hosts 2: the robot\'s TeMoto namespace (default %(default)s)')
    p.add_argument('--replug', action='store_true',
                   help='at the end, plug the first device back: the view fails back to it after a hold')
    p.add_argument('--standby', choices=('cold', 'warm', 'hot'), default='cold',
                   help='the view\'s standby policy: cold starts the next sensor on a failure, warm keeps its driver '
                   'running, hot also streams it into a hidden display (default %(default)s)')
    p.add_argument('--unplug-all', action='store_true',
                   help='once the first view is up, unplug every device of the view one right after another, '
                   'and time the action\'s "every sensor failed" from the last unplug (demo.json: all_failed_s)')
    p.add_argument('--voice', action='store_true',
                   help='say the instruction (espeak-ng) to the speech node instead of typing it; the failures '
                   'are announced (on a topic, in WAV files beside the bag, aloud with --live); the bag holds the '
                   'audio and what was heard')
    args = p.parse_args(argv)
    if args.unplug_all and (args.hosts == 2 or args.replug or args.kill_managers):
        p.error('--unplug-all runs alone: without --hosts 2, --replug and --kill-managers')
    if _no_two_hosts(p, args, 'temoto demo'):
        return 2
    if args.hosts == 2:
        if args.kill_managers:
            p.error('--kill-managers runs on one host; --hosts 2 does not take it yet')
        if not legal_name(args.robot, base=True) or args.robot == T.DEFAULT_NS:
            p.error('--robot %r: a TeMoto namespace (letters, digits, _) other than the station\'s %r'
                    % (args.robot, T.DEFAULT_NS))
    priority = [x.strip() for x in args.priority.split(',') if x.strip()]
    bad = [x for x in priority if x not in PRIORITY_ENTRIES]
    if bad or len(priority) < 2 or len(set(priority)) != len(priority):
        p.error('--priority must name 2 or 3 different entries from %s, got %r'
                % (', '.join(PRIORITY_ENTRIES), args.priority))
    if args.stage_timeout <= 0:
        p.error('--stage-timeout must be positive')
    if args.live and not os.environ.get('DISPLAY'):
        p.error('--live needs a DISPLAY')
    out = args.out or default_run_dir()
    opts = DemoOptions(out_dir=os.path.abspath(out), live=args.live, stage_timeout=args.stage_timeout,
                       modes={'d435': args.d435_mode, 'hokuyo': args.hokuyo_mode, 'sick': 'crash'},
                       priority=priority, report=not args.no_report, kill_managers=args.kill_managers,
                       seed=args.seed, hosts=args.hosts, robot=args.robot, standby=args.standby,
                       replug=args.replug, voice=args.voice, unplug_all=args.unplug_all)
    return run_demo(opts)
