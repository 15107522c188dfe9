"""The ER Manager's handle on its zygote (:mod:`temoto_er_manager.zygote`). No ROS in here.

Threading contract (the supervisor keeps it): :meth:`Zygote.start`,
:meth:`Zygote.wait_ready` and :meth:`Zygote.spawn` run on the supervisor's
spawner thread only (the zygote's death signal is relative to the thread that
forked it, and the control socket has one reader); :meth:`Zygote.read_events`
and :meth:`Zygote.ack` run on the reaper thread only.
"""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from typing import Optional

from temoto_core.forking import SINGLE_THREAD_ENV

from .zygote import MAX_MESSAGE, send

DEFAULT_MODULES = ['rospy', 'numpy', 'std_msgs.msg', 'sensor_msgs.msg']
_PKG_PARENT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_BOOT = ('import sys; sys.path[0] = %r; from temoto_er_manager.zygote import main; sys.exit(main(sys.argv[1:]))'
         % _PKG_PARENT)
# variables that change how the interpreter starts or what it imports: a node whose environment differs
# from the zygote's in one of them is started plainly (PYTHONUNBUFFERED is honoured by the child itself)
_START_VARS = ('PYTHONPATH', 'PYTHONHOME', 'PYTHONNOUSERSITE', 'PYTHONSAFEPATH', 'PYTHONOPTIMIZE',
               'PYTHONDONTWRITEBYTECODE', 'PYTHONHASHSEED', 'PYTHONWARNINGS', 'PYTHONDEVMODE', 'PYTHONUTF8',
               'PYTHONIOENCODING', 'PYTHONMALLOC', 'PYTHONFAULTHANDLER', 'PYTHONTRACEMALLOC', 'PYTHONPLATLIBDIR',
               'PYTHONUSERBASE', 'PYTHONSTARTUP', 'PYTHONINSPECT', 'PYTHONVERBOSE', 'PYTHONBREAKPOINT',
               'LD_PRELOAD', 'LD_LIBRARY_PATH', 'LC_ALL', 'LC_CTYPE', 'LANG') + tuple(SINGLE_THREAD_ENV)


class ZygoteError(Exception):
    """The zygote is unusable (did not start, died, refused or did not answer)."""


class Zygote:
    def __init__(self, modules: list, *, env: dict, log_path: str, python: str = sys.executable):
        self.modules = list(modules)
        self.python = python
        self.env = dict(env)                   # what a plain start would give a node (compatibility check)
        self.log_path = log_path
        self.popen: Optional[subprocess.Popen] = None
        self.pid = 0
        self.ready = False
        self.info: dict = {}
        self._ctrl: Optional[socket.socket] = None
        self._events: Optional[socket.socket] = None

    # -- spawner thread ------------------------------------------------------------------------------

    def start(self, die_with: int = 0) -> None:
        """Start the zygote. ``die_with``: the pid of the process whose thread starts it; the zygote then
        takes SIGKILL as its death signal itself, as it starts (no code runs between fork and exec here:
        see ``supervisor.py``), and exits at once if that process is already gone."""
        ctrl, ctrl_child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        events, events_child = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        env = dict(self.env)
        env.update(SINGLE_THREAD_ENV)
        os.makedirs(os.path.dirname(self.log_path) or '.', exist_ok=True)
        try:
            with open(self.log_path, 'ab', buffering=0) as log:
                self.popen = subprocess.Popen(
                    [self.python, '-c', _BOOT, str(ctrl_child.fileno()), str(events_child.fileno()),
                     json.dumps(self.modules), str(die_with)], env=env, cwd='/', stdin=subprocess.DEVNULL,
                    stdout=log, stderr=subprocess.STDOUT, pass_fds=(ctrl_child.fileno(), events_child.fileno()),
                    start_new_session=True)
        except OSError as e:
            ctrl.close()
            events.close()
            raise ZygoteError('cannot start the zygote: %s' % e) from e
        finally:
            ctrl_child.close()
            events_child.close()
        self.pid = self.popen.pid
        # blocking, whatever socket.setdefaulttimeout() says (rospy's XML-RPC code sets one): with a timeout,
        # Python waits for readability even with MSG_DONTWAIT, which would stall the reaper
        ctrl.settimeout(None)
        events.settimeout(None)
        self._ctrl, self._events = ctrl, events

    def wait_ready(self, timeout: float) -> dict:
        """Block until the zygote has imported its modules; its report ``{'failed': {module: error}, ...}``."""
        if self.ready:
            return self.info
        self.info = self._receive(timeout, 'preloading %s' % ', '.join(self.modules))
        if not self.info.get('ready'):
            raise ZygoteError('the zygote sent %r instead of its ready report' % self.info)
        self.ready = True
        return self.info

    def compatible(self, env: dict) -> bool:
        """A node with ``env`` starts from the zygote like it would from a fresh interpreter."""
        return all(env.get(k) == self.env.get(k) for k in _START_VARS)

    def spawn(self, argv: list, env: dict, cwd: Optional[str], log_fd: int, death_signal: int,
              timeout: float = 10.0) -> int:
        """Fork a child that runs ``argv[1]`` (a Python script) as ``__main__``; its pid."""
        try:
            send(self._ctrl, {'op': 'spawn', 'argv': list(argv), 'env': dict(env), 'cwd': cwd,
                              'death_signal': int(death_signal)}, fds=(log_fd,))
        except OSError as e:
            raise ZygoteError('cannot reach the zygote: %s' % e) from e
        reply = self._receive(timeout, 'a fork')
        if 'pid' not in reply:
            raise ZygoteError(reply.get('error') or 'the zygote answered %r' % reply)
        return int(reply['pid'])

    def _receive(self, timeout: float, what: str) -> dict:
        self._ctrl.settimeout(timeout)
        try:
            data = self._ctrl.recv(MAX_MESSAGE)
        except socket.timeout:
            raise ZygoteError('the zygote did not answer within %.1f s (%s)' % (timeout, what)) from None
        except OSError as e:
            raise ZygoteError('the zygote connection failed: %s' % e) from e
        if not data:
            raise ZygoteError('the zygote exited (%s); its output is in %s' % (self.exit_text(), self.log_path))
        return json.loads(data)

    def exit_text(self) -> str:
        try:
            rc = self.popen.wait(2.0)
        except subprocess.TimeoutExpired:
            return 'closed its socket'
        return 'exit code %d' % rc if rc >= 0 else 'signal %d' % -rc

    # -- reaper thread ------------------------------------------------------------------------------

    @property
    def events_fd(self) -> int:
        """The socket to select on, or -1 before the zygote started (or after it was closed)."""
        events = self._events
        return events.fileno() if events is not None else -1

    def read_events(self) -> tuple:
        """``(events, gone)`` without blocking: ``('exit', pid, returncode)`` and ``('reaped', pid, 0)`` in
        the order the zygote sent them; ``gone`` once it closed its end."""
        out = []
        while True:
            try:
                data = self._events.recv(MAX_MESSAGE, socket.MSG_DONTWAIT)
            except BlockingIOError:
                return out, False
            except OSError:
                return out, True
            if not data:
                return out, True
            msg = json.loads(data)
            if 'exit' in msg:
                out.append(('exit', int(msg['exit']), int(msg['rc'])))
            else:
                out.append(('reaped', int(msg['reaped']), 0))

    def ack(self, pid: int) -> None:
        """Let the zygote reap ``pid``: its exit is recorded, its group is never signalled again."""
        try:
            send(self._events, {'reap': pid})
        except OSError:
            pass                               # the zygote is gone; the orphan is reaped by init

    # -- any thread --------------------------------------------------------------------------------

    def close(self, timeout: float = 3.0) -> None:
        """End the zygote: EOF on its sockets, then SIGKILL if it lingers; reap it."""
        for s in (self._ctrl, self._events):
            if s is not None:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
        if self.popen is not None:
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(5.0)
        for s in (self._ctrl, self._events):
            if s is not None:
                s.close()

    def alive(self) -> bool:
        return self.popen is not None and self.popen.poll() is None
