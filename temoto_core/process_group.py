"""Process groups, handled without signalling a stranger.

Every child the project starts leads its own process group, so one signal
reaches the child and whatever it started. But a group id is only a pid: once
the leader is reaped and its group is empty, the number is free, and pid_max is
32768 on these machines, so it wraps within minutes of testing. A group may
therefore be signalled only while its leader is unreaped (a zombie leader
still holds the number). The helpers here make that rule easy to follow.
"""
import os
import subprocess
from typing import List, Optional


def exit_status(proc: subprocess.Popen) -> Optional[int]:
    """The child's exit code without reaping it (Popen convention: -N for signal N), or None if running."""
    if proc.returncode is not None:
        return proc.returncode
    try:
        info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
    except ChildProcessError:
        return proc.poll()
    if info is None:
        return None
    return -info.si_status if info.si_code in (os.CLD_KILLED, os.CLD_DUMPED) else info.si_status


def group_members(pgid: int, exclude: int = 0) -> List[int]:
    """Live (not zombie) processes in process group ``pgid``, from /proc."""
    members = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit() or int(entry) == exclude:
            continue
        try:
            with open('/proc/%s/stat' % entry, 'rb') as f:
                fields = f.read().rsplit(b')', 1)[1].split()
        except (OSError, IndexError):
            continue
        if len(fields) > 2 and int(fields[2]) == pgid and fields[0] != b'Z':
            members.append(int(entry))
    return members


def start_ticks(pid: int) -> Optional[int]:
    """When ``pid`` started, in clock ticks since boot (``/proc/<pid>/stat`` field 22); None if there is no
    such live process (gone, or a zombie).

    A pid and its start time name one process for as long as the machine runs: a pid that was reused
    belongs to a process that started later. Check both before acting on a pid that is not your child.
    """
    try:
        with open('/proc/%d/stat' % pid, 'rb') as f:
            fields = f.read().rsplit(b')', 1)[1].split()
    except (OSError, IndexError):
        return None
    if len(fields) < 20 or fields[0] in (b'Z', b'X'):
        return None
    return int(fields[19])
