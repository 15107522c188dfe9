#!/usr/bin/env python3
"""Run one launch file and exit as soon as any of its nodes dies.

``roslaunch`` alone keeps running when one of two nodes dies (unless that node
is ``required``), so a supervisor watching the ``roslaunch`` process never
learns about it. This runner uses roslaunch's API (``ROSLaunchParent``) with a
process listener: the first node death that was not asked for is printed
(node name and exit code, which end up in the resource's log tail), the rest of
the launch is shut down, and the runner exits with code 3. The ER Manager's
supervisor sees that exit at once and reports FAILED.

roslaunch puts every node in its own session (``os.setsid``), so a signal to
the runner's process group does not reach them. The runner therefore also gives
each node ``PR_SET_PDEATHSIG``: if the runner itself is killed, its nodes die
with it instead of being orphaned.

Usage: launch_runner.py [--sigint-timeout S] [--sigterm-timeout S] [--death-signal SIG] FILE [arg:=value ...]
Exit codes: 0 stopped on request (SIGINT/SIGTERM), 2 the launch could not start, 3 a node died.
Stand-alone on purpose (only roslaunch and the standard library): it runs with
the manager's interpreter without needing the project on PYTHONPATH.
"""
import argparse
import ctypes
import os
import signal
import sys
import threading

EXIT_STOPPED, EXIT_LAUNCH_ERROR, EXIT_NODE_DIED = 0, 2, 3
_PR_SET_PDEATHSIG = 1


def _install_node_death_signal(sig: int) -> None:
    """Make roslaunch's per-node ``preexec_fn`` (``os.setsid``) also set PDEATHSIG."""
    if not sig:
        return
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    real_setsid = os.setsid

    def setsid_and_die_with_runner():
        real_setsid()
        prctl(_PR_SET_PDEATHSIG, sig, 0, 0, 0)

    os.setsid = setsid_and_die_with_runner


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--sigint-timeout', type=float, default=3.0)
    parser.add_argument('--sigterm-timeout', type=float, default=2.0)
    parser.add_argument('--death-signal', default='SIGKILL')
    parser.add_argument('file')
    parser.add_argument('args', nargs='*', help='launch arguments name:=value')
    opts = parser.parse_args(argv)

    import roslaunch.parent
    import roslaunch.pmon
    import roslaunch.rlutil

    _install_node_death_signal(int(signal.Signals[opts.death_signal]) if opts.death_signal else 0)
    done = threading.Event()
    state = {'stopping': False, 'died': None}

    def on_signal(signum, _frame):
        state['stopping'] = True
        done.set()

    class Listener(roslaunch.pmon.ProcessListener):
        def process_died(self, process_name, exit_code):
            if state['stopping'] or state['died'] is not None:
                return
            state['died'] = (process_name, exit_code)
            if exit_code is None:
                how = 'without an exit code'
            elif exit_code < 0:
                try:
                    how = 'killed by %s (signal %d)' % (signal.Signals(-exit_code).name, -exit_code)
                except ValueError:
                    how = 'killed by signal %d' % -exit_code
            else:
                how = 'with exit code %d' % exit_code
            print('[launch_runner] node %s died %s; stopping the launch %s'
                  % (process_name, how, opts.file), flush=True)
            done.set()

    # installed first: roslaunch's own handler chains to these
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        uuid = roslaunch.rlutil.get_or_generate_uuid(None, False)
        parent = roslaunch.parent.ROSLaunchParent(
            uuid, [(opts.file, opts.args)], is_core=False, process_listeners=[Listener()],
            force_screen=True, show_summary=False,
            sigint_timeout=opts.sigint_timeout, sigterm_timeout=opts.sigterm_timeout)
        parent.start(auto_terminate=False)
    except Exception as e:          # bad XML, unknown package, no master, ...
        print('[launch_runner] cannot launch %s: %s' % (opts.file, e), flush=True)
        return EXIT_LAUNCH_ERROR
    print('[launch_runner] launched %s' % opts.file, flush=True)
    while not done.wait(1.0):      # a bounded wait keeps the main thread responsive to signals
        pass
    state['stopping'] = True
    parent.shutdown()
    if state['died'] is not None:
        return EXIT_NODE_DIED
    return EXIT_STOPPED


if __name__ == '__main__':
    sys.exit(main())
