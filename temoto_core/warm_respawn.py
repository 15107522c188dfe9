"""Warm respawn: a manager killed by a signal is forked again at once from a parent that has done its imports.

Why: a respawn by roslaunch starts a fresh interpreter, and importing ``rospy``, ``numpy`` (through genpy)
and a manager's modules takes 0.5 to 0.7 s here before the node can even register; the registry itself
comes back from the journal in a fraction of that (BENCHMARKS.md, bench_recovery.py). So a node with a
journal runs under a small parent that has imported everything: the parent forks the node, waits, and
when the node dies of a signal other than a stop (SIGKILL, SIGSEGV, the OOM killer) forks it again at once.

Rules it keeps:

- **Nothing outlives the parent.** Each node child gets ``PR_SET_PDEATHSIG`` (SIGKILL): a parent that is
  killed takes its node with it, and roslaunch's (or the demo's) respawn starts both again, cold.
- **A stop is a stop.** SIGINT or SIGTERM to the parent is passed to the node, and the parent ends with the
  node's exit status; a node that exits by itself (any exit code) is not respawned either.
- **No fork with threads** (``temoto_core.forking``, the rules the ER Manager's zygote follows too). numpy's
  BLAS starts a thread pool at import, so a parent that finds more than one thread starts itself once more
  with the pools set to one thread (the managers do no linear algebra). If that does not help, or without a
  journal, the node runs in the parent's process as it always did.
- **The parameters it started with.** A node reads its private parameters from the master as it starts,
  and a master that started again since (a robot host that lost power) has none: the node would come up
  with its defaults (another namespace, no journal), a different node under the same name. The parent
  reads the node's private parameters once, and puts them back before a fork if the master lost them.
- **Back-off for a crash loop.** A node that crashes by itself (SIGSEGV, SIGABRT, ...) within
  ``QUICK_DEATH_S`` of its start is forked again only after a growing delay, so a node that cannot start
  does not spin. A node that was killed (SIGKILL: an operator, the OOM killer, a chaos test) is forked
  again at once, as roslaunch's respawn does.
"""
from __future__ import annotations

import os
import signal
import sys
import time
from typing import Callable, Optional

import rosgraph
import rosgraph.names

from temoto_core.forking import SINGLE_THREAD_ENV, finish, fork, run_main, single_thread_env_set, thread_count

QUICK_DEATH_S = 2.0
BACKOFF_S = (0.0, 0.5, 1.0, 2.0, 5.0)
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def node_name(default: str, argv: list) -> str:
    """The node's full name as rospy will resolve it (``__name`` and ``__ns`` remaps, ROS_NAMESPACE)."""
    mappings = rosgraph.names.load_mappings(argv)
    return rosgraph.names.ns_join(rosgraph.names.get_ros_namespace(argv=argv), mappings.get('__name', default))


def journaled(name: str, argv: list) -> bool:
    """Whether the node's ``~journal`` parameter names a journal (read before the node exists: from its
    command line, ``_journal:=...``, or from the parameter server, where a launch file puts it)."""
    for arg in argv[1:]:
        if arg.startswith('_journal:='):
            return bool(arg.split(':=', 1)[1].strip())
    try:
        value = rosgraph.Master('/temoto_warm_respawn').getParam(rosgraph.names.ns_join(name, 'journal'))
    except Exception:                 # no master yet, or no such parameter: run the node as it is
        return False
    return bool(str(value).strip())


def run(main: Callable[[], int], default_name: str, argv: Optional[list] = None) -> int:
    """``main()`` under a warm-respawn parent if the node keeps a journal; else ``main()`` as it is."""
    argv = sys.argv if argv is None else argv
    name = node_name(default_name, argv)
    if not journaled(name, argv):
        return main()
    if thread_count() != 1:
        if not single_thread_env_set():
            env = dict(os.environ, **SINGLE_THREAD_ENV)
            os.execve(sys.executable, [sys.executable] + list(argv), env)     # never returns
        sys.stderr.write('%s: warm respawn off: %d threads after the imports\n' % (name, thread_count()))
        return main()
    return _Parent(main, name).serve()


def private_params(name: str) -> Optional[dict]:
    """The node's private parameters on the master now (None if it has none, or no master answers)."""
    try:
        value = rosgraph.Master('/temoto_warm_respawn').getParam(name)
    except Exception:                 # rosgraph raises for a missing key, and OSError without a master
        return None
    return value if isinstance(value, dict) else None


def restore_params(name: str, params: Optional[dict]) -> bool:
    """Put ``params`` back under the node's name if the master has none there (True if it did)."""
    if not params or private_params(name) is not None:
        return False
    try:
        rosgraph.Master('/temoto_warm_respawn').setParam(name, params)
    except Exception as e:            # no master: the node waits for one as it always does
        sys.stderr.write('%s: could not put its parameters back: %s\n' % (name, e))
        return False
    return True


class _Parent:
    def __init__(self, main: Callable[[], int], name: str) -> None:
        self.main = main
        self.name = name
        self.child = 0
        self.stopping = False
        self.params = private_params(name)       # what the node started with

    def _forward(self, signum: int, _frame) -> None:
        self.stopping = True
        if self.child:
            try:
                os.kill(self.child, signum)
            except ProcessLookupError:
                pass

    def serve(self) -> int:
        for sig in STOP_SIGNALS:
            signal.signal(sig, self._forward)
        quick = 0
        while True:
            started = time.monotonic()
            self.child = self._fork()
            status = self._wait()
            code = os.waitstatus_to_exitcode(status)
            if self.stopping or code >= 0 or -code in STOP_SIGNALS:
                return code if code >= 0 else 128 - code
            crashed = -code != signal.SIGKILL
            quick = quick + 1 if crashed and time.monotonic() - started < QUICK_DEATH_S else 0
            delay = BACKOFF_S[min(quick, len(BACKOFF_S) - 1)]
            sys.stderr.write('%s: the node (pid %d) was killed by %s; forking it again%s\n'
                             % (self.name, self.child, signal.Signals(-code).name,
                                ' in %.1f s' % delay if delay else ''))
            if delay:
                time.sleep(delay)            # back-off between respawns, as roslaunch's respawn_delay
            if self.stopping:
                return 128 - code
            if restore_params(self.name, self.params):
                sys.stderr.write('%s: the master had lost its parameters (it started again); put them back\n'
                                 % self.name)

    def _fork(self) -> int:
        pid = fork(signal.SIGKILL)      # thread_count() was 1 when run() chose a parent, and it starts none
        if pid:
            return pid
        code = 1
        try:
            for sig in STOP_SIGNALS:
                signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)
            code = run_main(self.main)
            finish(code)
        finally:
            os._exit(code)

    def _wait(self) -> int:
        while True:
            try:
                _, status = os.waitpid(self.child, 0)
                return status
            except InterruptedError:       # a stop signal: passed on; keep waiting for the node
                continue
