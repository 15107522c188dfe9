"""A child that must die with the thread that starts it (``process_group.popen_dying_with_this_thread``).

Its setup runs between fork and exec, so the fork runs the interpreter's before-fork hooks: logging's takes
the logging module lock, then the interpreter takes the import lock. Started while another thread held the
import lock, it held logging's lock until that thread let go; a thread that imports and needs logging's lock
(a garbage collection in it can) then waited for good, and so did every log call of the process. That is
how the robot's ER Manager of the chaos history wedged (seed 17: every rospy log call stopped, its spawner
stopped in a start). The import lock is now taken first, in the order an import takes the two.
"""
import _imp
import inspect
import logging
import signal
import subprocess
import sys
import threading

from temoto_core.process_group import popen_dying_with_this_thread
from temoto_testing import wait_for

HANG = 20.0


def innermost(thread: threading.Thread):
    frame = sys._current_frames().get(thread.ident)
    return (frame.f_code.co_name, frame.f_lineno) if frame is not None else None


def in_function(thread: threading.Thread, name: str) -> bool:
    frame = sys._current_frames().get(thread.ident)
    while frame is not None:
        if frame.f_code.co_name == name:
            return True
        frame = frame.f_back
    return False


def test_a_start_waits_for_the_import_lock_before_it_takes_the_logging_lock():
    lines, first = inspect.getsourcelines(popen_dying_with_this_thread)
    taking = [first + i for i, line in enumerate(lines) if '_imp.acquire_lock()' in line]
    assert taking, 'the start no longer takes the import lock before it forks'
    release, started = threading.Event(), []

    def importer():                       # holds the import lock, as a thread looking for a module does
        _imp.acquire_lock()
        try:
            release.wait(HANG)
        finally:
            _imp.release_lock()

    def starter():                        # lives until its child exits: the child dies with this thread
        child = popen_dying_with_this_thread(['true'], signal.SIGKILL, stdout=subprocess.DEVNULL)
        started.append(child.wait(HANG))

    holder = threading.Thread(target=importer, daemon=True)
    holder.start()
    wait_for(lambda: in_function(holder, 'wait'), HANG, 'the import lock to be held')
    start = threading.Thread(target=starter, daemon=True)
    start.start()
    try:
        # without the import lock taken first, the start would wait for it inside the fork's before-fork
        # hooks, holding logging's lock, and never get here
        wait_for(lambda: innermost(start) == ('popen_dying_with_this_thread', taking[0]), HANG,
                 'the start to wait for the import lock')
        assert 'owner=%d ' % start.ident not in repr(logging._lock)
        assert logging._lock.acquire(timeout=HANG), 'logging\'s lock is held while the start waits'
        logging._lock.release()
    finally:
        release.set()
        holder.join(HANG)
        start.join(HANG)
    assert started == [0]


FORKS = '''
import os, signal, sys
from temoto_core.process_group import die_with_parent
parent = os.getpid()
results = []
for claimed in (parent, parent + 1000000):          # its real parent; one that is not (it "died" meanwhile)
    pid = os.fork()
    if pid == 0:
        os._exit(0 if die_with_parent(signal.SIGKILL, claimed) else 3)
    results.append(os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]))
print(results, flush=True)
'''


def test_one_death_signal_helper_for_every_fork_and_its_race():
    """The ER Manager's children, the zygote's and the warm-respawn parent's all use process_group's
    die_with_parent: it sets the death signal and tells whether the parent was already gone (that a child
    then dies with its parent is what test_warm_respawn's orphan test and test_er_supervisor's show)."""
    out = subprocess.run([sys.executable, '-c', FORKS], capture_output=True, text=True, timeout=HANG)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[0, 3]'
