"""Forking a Python process that has done its imports: the rules, written once.

Two fork servers use this, because each keeps a different promise:
- the ER Manager's zygote (``temoto_er_manager/zygote.py``) forks a new child per Python driver
  on request, over a socket, so that a driver skips its imports;
- the warm-respawn parent (``temoto_core/warm_respawn.py``) forks the *same* manager node again
  when it is killed, so that its registry is back before a cold interpreter could register.

What both must get right is here:
- **No fork with threads.** A thread does not survive a fork, and a lock it held stays locked in
  the child. numpy's BLAS starts a thread pool at import unless told not to
  (``SINGLE_THREAD_ENV``), so a fork server sets those variables before numpy is imported, and
  :func:`fork` refuses while the process has more than one thread.
- **Nothing outlives its parent.** The child's death signal is set relative to the forking
  parent before anything else runs (``process_group.die_with_parent``); a parent that died
  meanwhile makes the child exit at once.
- **A forked child ends as an interpreter would** (:func:`finish`): it waits for its non-daemon
  threads, runs ``atexit`` (rospy's shutdown hooks), flushes, and dies by the signal that
  interrupted it, so whoever waits on it sees what a plain ``python script`` would have given.
"""
from __future__ import annotations

import atexit
import os
import signal
import sys
import threading
import traceback
from typing import Any, Callable, NoReturn

from temoto_core.process_group import die_with_parent

# set in a fork server's environment so that BLAS and OpenMP libraries start no thread pools at import
SINGLE_THREAD_ENV = {k: '1' for k in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS',
                                       'NUMEXPR_NUM_THREADS', 'VECLIB_MAXIMUM_THREADS', 'GOTO_NUM_THREADS',
                                       'BLIS_NUM_THREADS')}
# the exit code of a child whose parent died before its death signal took effect
PARENT_GONE = 125


class ForkRefused(RuntimeError):
    """The process has threads: a fork would copy locks that no thread will ever release."""


def thread_count() -> int:
    """Threads of this process as the kernel sees them (native ones included)."""
    try:
        return len(os.listdir('/proc/self/task'))
    except OSError:
        return 1


def single_thread_env_set() -> bool:
    """Whether this process was started with the thread pools off."""
    return all(os.environ.get(k) == v for k, v in SINGLE_THREAD_ENV.items())


def fork(death_signal: int) -> int:
    """Fork this single-threaded process: the child's pid in the parent, 0 in the child.

    In the child, ``death_signal`` is already set relative to the parent (0: none), and a child whose
    parent died before that took effect has exited with ``PARENT_GONE``. Raises :class:`ForkRefused`
    when the process has more than one thread.
    """
    threads = thread_count()
    if threads != 1:
        raise ForkRefused('the process has %d threads; it forks only single-threaded' % threads)
    parent = os.getpid()
    pid = os.fork()
    if pid == 0 and death_signal and not die_with_parent(death_signal, parent):
        os._exit(PARENT_GONE)
    return pid


def exit_code(e: SystemExit) -> int:
    """The exit code the interpreter gives an uncaught ``SystemExit`` (printing a non-int code, as it does)."""
    if e.code is None:
        return 0
    if isinstance(e.code, int):
        return e.code & 0xff
    try:
        print(e.code, file=sys.stderr)
    except BaseException:
        pass
    return 1


def run_main(body: Callable[[], Any], print_exception: Callable[[BaseException], None] = traceback.print_exception
             ) -> int:
    """Run a forked child's ``body`` as an interpreter runs ``__main__``; the exit code (an int that ``body``
    returns, else 0), or ``-SIGINT`` for an uncaught KeyboardInterrupt (Python dies of the signal then)."""
    try:
        code = body()
        return code & 0xff if isinstance(code, int) and not isinstance(code, bool) else 0
    except SystemExit as e:
        return exit_code(e)
    except KeyboardInterrupt as e:
        print_exception(e)
        return -signal.SIGINT
    except BaseException as e:
        print_exception(e)
        return 1


def finish(code: int) -> NoReturn:
    """End a forked child as ``Py_FinalizeEx`` would, in its order: non-daemon threads, ``atexit``, flush;
    then exit with ``code``, or die of signal ``-code`` when it is negative."""
    try:
        threading._shutdown()
    except BaseException:
        traceback.print_exc()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except BaseException:
            pass
    if code < 0:
        signal.signal(-code, signal.SIG_DFL)
        os.kill(os.getpid(), -code)
        code = 128 - code
    os._exit(code)
