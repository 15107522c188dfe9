"""Process groups, handled without signalling a stranger.

Every child the project starts leads its own process group, so one signal
reaches the child and whatever it started. But a group id is only a pid: once
the leader is reaped and its group is empty, the number is free, and pid_max is
32768 on these machines, so it wraps within minutes of testing. A group may
therefore be signalled only while its leader is unreaped (a zombie leader
still holds the number). The helpers here make that rule easy to follow.
"""
import _imp
import ctypes
import os
import signal
import subprocess
from typing import Callable, List, Optional, Sequence, Tuple

_PR_SET_PDEATHSIG = 1
_libc = ctypes.CDLL(None, use_errno=True)
_prctl = _libc.prctl          # resolved before any fork: the child must not load anything
_signal = _libc.signal        # likewise: the C library's own signal(), callable between fork and exec
_signal.argtypes = (ctypes.c_int, ctypes.c_void_p)
_signal.restype = ctypes.c_void_p
_SIG_DFL = None               # NULL


KILL_GRACE_S = 5.0       # s a SIGKILLed process has to be seen gone (it cannot refuse; only the reap lags)


def stop_stages(sigint_grace: float, sigterm_grace: float) -> Tuple[Tuple[int, float], ...]:
    """The stop every TeMoto process gets: SIGINT (a node shuts down cleanly), SIGTERM, then SIGKILL, each
    with the time it has before the next."""
    return ((signal.SIGINT, sigint_grace), (signal.SIGTERM, sigterm_grace), (signal.SIGKILL, KILL_GRACE_S))


def escalate(stages: Sequence[Tuple[int, float]], send: Callable[[int], None],
             ended: Callable[[float], bool]) -> bool:
    """Stop a process by ``stages``: each (signal, grace) is sent with ``send(signal)`` unless the process has
    ended, then ``ended(grace)`` waits for it at most the grace. True once it ended, False if it outlived
    every stage. How to signal (a group, only while its leader is unreaped) and how to see the end (a reap,
    a pidfd, an event) are the caller's; the order and the waits are the same for every process."""
    for sig, grace in stages:
        if ended(0.0):
            return True
        send(sig)
        if ended(grace):
            return True
    return False


def die_with_parent(death_signal: int, parent: int) -> bool:
    """In a child just forked from ``parent``: have the kernel send it ``death_signal`` when the parent's
    forking thread exits (``PR_SET_PDEATHSIG``). False if the parent died before that took effect (the child
    has been adopted already and will never get the signal): the caller exits at once. Safe between fork and
    exec: the C function was resolved at import, and nothing is allocated or imported."""
    _prctl(_PR_SET_PDEATHSIG, int(death_signal), 0, 0, 0)
    return os.getppid() == parent


def popen_dying_with_this_thread(argv: Sequence[str], death_signal: int, default_signals: Sequence[int] = (),
                                 **kwargs) -> subprocess.Popen:
    """``subprocess.Popen(argv, **kwargs)``, whose child gets ``death_signal`` when the calling thread exits
    (``PR_SET_PDEATHSIG``; 0: none), and exits at once if this process died before that took effect; the
    signals ``default_signals`` are set back to their default in it.

    That is done between fork and exec (a ``preexec_fn``), and a fork with one runs the interpreter's
    before-fork hooks: logging's takes the logging module lock, then the interpreter takes the import lock.
    A thread that imports a module holds the import lock, and a garbage collection in it may need the
    logging lock: the two would wait for each other for good, and so would every log call of the process
    (rospy's take that lock on every call). A stress of such starts beside imports, log calls and
    collections wedged 4 runs in 6 within 40 s. So the import lock is taken here first, in the order an
    import takes the two; the stress then wedged none in 9. Prefer a plain ``Popen`` when the child needs
    none of this (Python handlers of signals are reset by exec anyway).
    """
    parent = os.getpid()

    def in_child() -> None:           # between fork and exec: no allocation, no imports
        for sig in default_signals:
            _signal(int(sig), _SIG_DFL)
        if death_signal and not die_with_parent(death_signal, parent):
            os._exit(125)
    _imp.acquire_lock()
    try:
        return subprocess.Popen(list(argv), preexec_fn=in_child, **kwargs)
    finally:
        _imp.release_lock()


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


def ended(pid: int) -> bool:
    """Whether process ``pid`` has ended with every one of its threads: gone, or a zombie with its leader alone.

    The leader of a killed process can read as a zombie while its other threads are still exiting, and
    those hold the process's files: its sockets are still open, and a peer still finds it connected. A
    test that sent a goal once the leader read 'Z' had it accepted by a navigator that still saw the
    killed Robot Manager's connection, closed some milliseconds later.
    """
    try:
        with open('/proc/%d/stat' % pid, 'rb') as f:
            state = f.read().rsplit(b')', 1)[1].split()[0]
        threads = os.listdir('/proc/%d/task' % pid)
    except (FileNotFoundError, ProcessLookupError):
        return True
    except IndexError:                       # a stat cut short: the process is being torn down
        return False
    return state in (b'Z', b'X') and threads in ([], [str(pid)])


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
