"""A fork server ("zygote") for Python node scripts: import once, fork per node.

Why: a Python node spends most of its start-up importing ``rospy``, ``numpy`` and
message modules (~0.25-0.4 s on the demo machine, more when two nodes of a launch
file start together on 2 cores). The zygote is a single-threaded helper process
the ER Manager starts once, with the manager's interpreter and environment; it
imports ``preload_modules`` and then forks a child per Python node. The child
turns itself into the node (session, death signal, cwd, env, stdio, argv) and
runs the script with :func:`runpy.run_path`, so it skips those imports.

Process tree and lifetime::

    ER Manager --PR_SET_PDEATHSIG(SIGKILL)--> zygote --PR_SET_PDEATHSIG(death_signal)--> node children

The zygote dies with the manager (its death signal is relative to the manager's
spawner thread) and also exits when its sockets reach EOF; the children's death
signal is relative to the zygote, so a SIGKILLed manager takes the zygote and
then every child with it.

Two ``SOCK_SEQPACKET`` socket pairs (one JSON message per packet):

- *control* (the manager's spawner thread only): the zygote first sends
  ``{"ready": ..., "failed": {module: error}}``; then per request
  ``{"op": "spawn", argv, env, cwd, death_signal}`` + the log file descriptor
  (SCM_RIGHTS) is answered ``{"pid": N}`` or ``{"error": "..."}``;
- *events* (the manager's reaper thread only): the zygote sends
  ``{"exit": pid, "rc": returncode}`` as soon as a child has exited, but does
  **not** reap it (``waitid(WNOWAIT)``); it reaps only when the manager answers
  ``{"reap": pid}`` (and confirms with ``{"reaped": pid}``, so that a stop
  returns only once the child is gone). The manager sends that after it has recorded the exit under
  the process's lock, the same lock under which it signals the child's group. So
  the rule of :mod:`temoto_core.process_group` holds: a group is signalled only
  while its leader is unreaped (the zombie holds the id).

Differences from a plain ``python script`` start (documented, deliberate):

- the fork follows ``temoto_core.forking``, as the warm-respawn parent's does:
  BLAS/OpenMP pools are set to one thread before numpy is imported, so that no
  thread exists at fork time, and the zygote forks only single-threaded (a
  node's numpy therefore runs single-threaded BLAS); the child ends as a plain
  interpreter would;
- modules imported by the zygote saw the manager's environment and argv at
  import time. ``rospy.names`` reads both at import and is re-initialised in the
  child; other preloaded modules must not capture the environment at import;
- ``/proc/<pid>/cmdline`` and ``/proc/<pid>/environ`` show the zygote's; the
  process name (``comm``, what ``ps -o comm``/``pgrep`` show) is the script's;
- all children share the zygote's hash seed; ``random`` and ``numpy.random`` are
  reseeded in each child.
"""
from __future__ import annotations

import ctypes
import importlib
import io
import json
import os
import runpy
import select
import signal
import socket
import sys
import traceback

from temoto_core.forking import ForkRefused, fork, finish, run_main, thread_count
from temoto_core.process_group import die_with_parent

_PR_SET_NAME = 15
MAX_MESSAGE = 1 << 20


def send(sock: socket.socket, message: dict, fds: tuple = ()) -> None:
    data = json.dumps(message).encode()
    if fds:
        socket.send_fds(sock, [data], list(fds))
    else:
        sock.send(data)


def returncode(status: int) -> int:
    """A wait status in the Popen convention (-N: killed by signal N)."""
    return os.waitstatus_to_exitcode(status)


# -- the zygote process ----------------------------------------------------------------------------

class _Server:
    def __init__(self, ctrl: socket.socket, events: socket.socket):
        self.ctrl = ctrl
        self.events = events
        self.children: dict[int, bool] = {}      # pid -> exit already reported
        self.libc = ctypes.CDLL(None, use_errno=True)
        self.wake_r, self.wake_w = os.pipe2(os.O_CLOEXEC | os.O_NONBLOCK)
        signal.set_wakeup_fd(self.wake_w)
        signal.signal(signal.SIGCHLD, lambda *_: None)   # the wake-up fd does the work
        signal.signal(signal.SIGINT, signal.SIG_IGN)     # it lives in its own session; EOF ends it

    def preload(self, modules: list) -> None:
        failed = {}
        for name in modules:
            try:
                importlib.import_module(name)
            except BaseException as e:             # a module that cannot load is reported, not fatal
                failed[name] = '%s: %s' % (type(e).__name__, e)
        send(self.ctrl, {'ready': True, 'pid': os.getpid(), 'failed': failed, 'threads': thread_count()})

    def serve(self) -> None:
        while True:
            readable, _, _ = select.select([self.ctrl, self.events, self.wake_r], [], [])
            if self.wake_r in readable:
                try:
                    while os.read(self.wake_r, 4096):
                        pass
                except BlockingIOError:
                    pass
            self.report_exits()                     # a SIGCHLD may have been merged with other wake-ups
            if self.events in readable:
                data = self.events.recv(MAX_MESSAGE)
                if not data:
                    return
                pid = json.loads(data).get('reap')
                if isinstance(pid, int) and pid in self.children:
                    os.waitpid(pid, 0)              # a zombie already: returns at once
                    del self.children[pid]
                    send(self.events, {'reaped': pid})
            if self.ctrl in readable:
                data, fds, _flags, _addr = socket.recv_fds(self.ctrl, MAX_MESSAGE, 1)
                if not data:
                    return
                try:
                    self.spawn(json.loads(data), fds)
                finally:
                    for fd in fds:
                        os.close(fd)

    def report_exits(self) -> None:
        for pid, reported in list(self.children.items()):
            if reported:
                continue
            try:
                info = os.waitid(os.P_PID, pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
            except ChildProcessError:
                info = None
                self.children.pop(pid, None)
            if info is None:
                continue
            rc = -info.si_status if info.si_code in (os.CLD_KILLED, os.CLD_DUMPED) else info.si_status
            self.children[pid] = True
            send(self.events, {'exit': pid, 'rc': rc})

    def spawn(self, req: dict, fds: list) -> None:
        if req.get('op') != 'spawn' or len(fds) != 1:
            send(self.ctrl, {'error': 'bad request to the zygote: %r' % (req.get('op'),)})
            return
        try:
            pid = fork(int(req.get('death_signal') or 0))
        except (ForkRefused, ValueError, TypeError) as e:
            send(self.ctrl, {'error': 'the zygote cannot fork: %s' % e})
            return
        if pid == 0:
            _child(self, req, fds[0])                # never returns
        self.children[pid] = False
        send(self.ctrl, {'pid': pid})


def _child(server: _Server, req: dict, log_fd: int) -> None:
    """In the forked child (its death signal set): become the node, run its script, exit with its status.
    Never returns."""
    code = 127
    try:
        try:
            os.setsid()
            signal.set_wakeup_fd(-1)
            for sig in (signal.SIGCHLD, signal.SIGTERM, signal.SIGHUP, signal.SIGQUIT, signal.SIGUSR1,
                        signal.SIGUSR2):
                signal.signal(sig, signal.SIG_DFL)
            signal.signal(signal.SIGINT, signal.default_int_handler)    # as a fresh interpreter has it
            signal.pthread_sigmask(signal.SIG_SETMASK, [])
            for fd in (server.wake_r, server.wake_w):
                os.close(fd)
            server.ctrl.close()
            server.events.close()
            null = os.open(os.devnull, os.O_RDONLY)
            os.dup2(null, 0)
            os.close(null)
            os.dup2(log_fd, 1)
            os.dup2(log_fd, 2)
            os.close(log_fd)
            _reopen_stdio()
            argv, env = list(req['argv']), dict(req['env'])
            script = argv[1]
            if req.get('cwd'):
                os.chdir(req['cwd'])
            os.environ.clear()
            os.environ.update(env)
            sys.argv = argv[1:]
            sys.path[0] = os.path.dirname(os.path.abspath(script))
            name = os.path.basename(script).encode()[:15]
            server.libc.prctl(_PR_SET_NAME, ctypes.c_char_p(name), 0, 0, 0)
            _reset_preloaded_state()
        except BaseException as e:
            os.write(2, ('[temoto_er_manager zygote] cannot start %r: %s: %s\n'
                         % (req.get('argv'), type(e).__name__, e)).encode())
            os._exit(127)
        code = run_main(lambda: runpy.run_path(script, run_name='__main__'),
                        lambda e: _print_exception(e, script))
        finish(code)
    finally:
        os._exit(code)


def _reopen_stdio() -> None:
    sys.stdin = io.TextIOWrapper(io.FileIO(0, 'r', closefd=False), encoding='utf-8')
    # unbuffered, as the manager asks with PYTHONUNBUFFERED: a crash's last lines must reach the log
    sys.stdout = io.TextIOWrapper(io.FileIO(1, 'w', closefd=False), encoding='utf-8', write_through=True)
    sys.stderr = io.TextIOWrapper(io.FileIO(2, 'w', closefd=False), encoding='utf-8', errors='backslashreplace',
                                  write_through=True)
    sys.__stdin__, sys.__stdout__, sys.__stderr__ = sys.stdin, sys.stdout, sys.stderr


def _reset_preloaded_state() -> None:
    """Undo what preloaded modules captured from the zygote's argv and environment at import."""
    names = sys.modules.get('rospy.names')
    if names is not None:
        from rosgraph.names import get_ros_namespace   # lazy: only when a preloaded module brought rospy
        names.reload_mappings(sys.argv)
        names._caller_namespace = get_ros_namespace()
        names._caller_id = names._caller_namespace + 'unnamed'
    nprandom = sys.modules.get('numpy.random')
    if nprandom is not None:
        nprandom.seed()


def _print_exception(e: BaseException, script: str) -> None:
    """The traceback a plain interpreter prints: from the script's frame on, without the zygote's."""
    tb = e.__traceback__
    while tb is not None and tb.tb_frame.f_code.co_filename != script:
        tb = tb.tb_next
    traceback.print_exception(type(e), e, tb or e.__traceback__)


def main(argv: list) -> int:
    """``python -m temoto_er_manager.zygote CTRL_FD EVENTS_FD MODULES_JSON [DIE_WITH]``

    ``DIE_WITH``: the pid of the manager; the zygote dies with the manager's thread that started it
    (SIGKILL), and exits at once if the manager died before that took effect."""
    die_with = int(argv[3]) if len(argv) > 3 else 0
    if die_with and not die_with_parent(signal.SIGKILL, die_with):
        return 125
    ctrl = socket.socket(fileno=int(argv[0]))
    events = socket.socket(fileno=int(argv[1]))
    ctrl.settimeout(None)                          # blocking whatever a preloaded module sets as default
    events.settimeout(None)
    server = _Server(ctrl, events)
    server.preload(json.loads(argv[2]))
    try:
        server.serve()
    except (ConnectionError, OSError):
        pass
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
