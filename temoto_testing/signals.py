"""Stopping a process for a test, and knowing that it has stopped.

``kill(pid, SIGSTOP)`` returns before the process stops: the kernel stops it once one of its threads
handles the signal, and on a loaded machine that thread may wait for a CPU while another thread of the
process still runs. A test that then asks the process something may get its answer (the chaos reader's
test did, 1 run in 6 beside a chaos history). ``stop`` returns once every thread is stopped.
"""
import os
import signal
from typing import List

from temoto_core.wait import wait_for

STOPPED_STATES = ('T', 't')      # stopped by a signal, or traced and stopped


def _threads_stopped(pid: int) -> bool:
    try:
        tids = os.listdir('/proc/%d/task' % pid)
    except FileNotFoundError:
        return True                     # gone: nothing of it runs
    for tid in tids:
        try:
            with open('/proc/%d/task/%s/stat' % (pid, tid)) as f:
                stat = f.read()
        except FileNotFoundError:
            continue                    # that thread ended
        # the state follows the command name, which is in parentheses and may hold spaces
        if stat[stat.rindex(')') + 2] not in STOPPED_STATES:
            return False
    return True


def group_members(pgid: int) -> List[int]:
    """The processes of the process group ``pgid``."""
    members = []
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                if os.getpgid(int(entry)) == pgid:
                    members.append(int(entry))
            except ProcessLookupError:
                pass
    return members


def stop(pid: int, group: bool = False, timeout: float = 10.0) -> None:
    """SIGSTOP the process ``pid`` (or its whole process group), and return once every thread of it is
    stopped; TimeoutError after ``timeout`` s."""
    if group:
        os.killpg(pid, signal.SIGSTOP)
        wait_for(lambda: all(_threads_stopped(p) for p in group_members(pid)), timeout,
                 'process group %d to stop' % pid)
    else:
        os.kill(pid, signal.SIGSTOP)
        wait_for(lambda: _threads_stopped(pid), timeout, 'process %d to stop' % pid)
