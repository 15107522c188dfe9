"""Start, watch, stop and reap child processes. No ROS in here.

Why it looks like this (each point fixes a flaw of the original, see
the original):

- **No shell.** A child is started from an argv list; nothing is ever parsed by
  ``/bin/sh``.
- **Own process group.** Every child starts with ``start_new_session=True``, so
  a stop signal reaches the child and everything it spawned in its group.
- **Event-driven exit detection.** One reaper thread blocks in ``select`` on a
  pidfd per child (``os.pidfd_open``). A child's death wakes it at once; it reaps
  the child (no zombie) and hands an :class:`ExitInfo` to ``on_exit`` unless the
  exit was asked for (an intentional stop is never reported as a failure).
- **Escalating stop.** SIGINT to the group, then SIGTERM, then SIGKILL, with
  configurable grace periods; the stop returns only once the child is reaped.
- **Children die with the manager, or are kept on a leash.** Without a
  ``leash``, each child gets ``PR_SET_PDEATHSIG`` (``death_signal``, SIGKILL by
  default) so that a SIGKILLed manager leaves no orphan that nobody can stop or
  watch. The kernel sends the signal when the *thread* that forked the child
  exits, so every fork happens on one spawner thread that lives as long as the
  supervisor (rospy runs each service request in a short-lived thread, which
  would otherwise kill the child as soon as the request returned). With a
  ``leash`` (:mod:`temoto_er_manager.leash`, a manager with a journal), children
  outlive the manager: the leash is told of each one, a restarted manager
  :meth:`adopts <ProcessSupervisor.adopt>` them, and the leash stops those that
  nobody adopts within its bound.
- **Optional preloading.** With ``preload_modules``, Python node scripts
  (``ProcessSpec.preloadable``) are forked from a zygote that has already
  imported those modules (:mod:`temoto_er_manager.zygote`), which saves most of
  a Python node's start-up. The zygote reports each child's exit over a socket
  and reaps it only after the supervisor has recorded the exit, so the rules
  above hold for those children too. If the zygote cannot be used (it died, did
  not start, refused a fork), nodes are started plainly and the log says so.
"""
from __future__ import annotations

import errno
import faulthandler
import itertools
import logging
import os
import queue
import select
import shlex
import signal
import subprocess
import threading
import time
from collections import deque
from concurrent.futures import Future, TimeoutError as FutureTimeout
from dataclasses import dataclass, field
from typing import Callable, List, Optional

from temoto_core import watchdog
from temoto_core.process_group import (escalate, group_members, popen_dying_with_this_thread, start_ticks,
                                        stop_stages)

from .preload import Zygote, ZygoteError

_log = logging.getLogger('temoto_er_manager.supervisor')
SPAWN_SLACK_S = 10.0      # beyond the zygote's imports, for a spawn on a loaded machine

# A child must answer the stop signals whatever its parent does with them: a manager started from a
# script's background job inherits SIGINT ignored, and its children would then only stop at SIGTERM.
# (A signal this process handles in Python is answered by default after exec anyway.)
_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class SupervisorError(Exception):
    """A process could not be started, or did not become ready."""


class SpawnerStuck(SupervisorError):
    """The spawner thread did not start a process within its bound: the manager's fault, not the request's."""


class ProcessExitedEarly(SupervisorError):
    """The child exited before it was ready."""

    def __init__(self, message: str, exit_info: 'ExitInfo'):
        super().__init__(message)
        self.exit_info = exit_info


class StartCancelled(SupervisorError):
    """The process was stopped (unload, shutdown) while it was still starting."""


class ReadyTimeout(SupervisorError):
    """The child stayed alive but did not become ready in time."""


@dataclass
class ProcessSpec:
    """What to run and how. ``argv[0]`` is an absolute path or a name looked up in ``env['PATH']``."""
    argv: list[str]
    env: dict[str, str]
    log_path: str
    cwd: Optional[str] = None
    label: str = ''                 # free text for messages and listings, e.g. "pkg/exe"
    node_names: list[str] = field(default_factory=list)   # ROS nodes that must register
    preloadable: bool = False       # argv = [this interpreter, a Python script, args...]: may come from the zygote

    @property
    def command(self) -> str:
        return shlex.join(self.argv)


@dataclass
class ExitInfo:
    pid: int
    returncode: int                 # Popen convention: -N means killed by signal N
    command: str
    log_tail: str
    intentional: bool
    when: float                     # time.time() of detection
    detail: str = ''                # replaces the reason when the exit status is not known

    @property
    def reason(self) -> str:
        return self.detail or describe_returncode(self.returncode, self.intentional)

    def message(self) -> str:
        tail = self.log_tail.rstrip()
        text = 'process %d (%s) %s' % (self.pid, self.command, self.reason)
        return text + ('; last output:\n' + tail if tail else '; no output')


def describe_returncode(rc: int, intentional: bool = False) -> str:
    if rc < 0:
        try:
            name = signal.Signals(-rc).name
        except ValueError:
            name = 'signal %d' % -rc
        return 'was killed by %s (signal %d)' % (name, -rc)
    if rc == 0:
        return 'exited with code 0' + ('' if intentional else ' (a clean exit while the resource was still in use)')
    return 'exited with code %d' % rc


def read_tail(path: str, lines: int, max_bytes: int = 16384) -> str:
    """The last ``lines`` lines of a log file (reads at most ``max_bytes`` from its end)."""
    try:
        with open(path, 'rb') as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - max_bytes))
            data = f.read()
    except OSError:
        return ''
    text = data.decode('utf-8', errors='replace')
    return '\n'.join(text.splitlines()[-lines:])


def _pidfd_readable(pidfd: int) -> bool:
    """The process behind ``pidfd`` has exited."""
    try:
        return bool(select.select([pidfd], [], [], 0)[0])
    except (OSError, ValueError):
        return True


class ManagedProcess:
    """One child. Its state changes are announced on ``cond``."""

    _ids = itertools.count(1)

    def __init__(self, spec: ProcessSpec, pid: int, pidfd: int, started: float,
                 popen: Optional[subprocess.Popen] = None, zygote: Optional[Zygote] = None):
        self.key = next(self._ids)
        self.spec = spec
        self.popen = popen                  # a plain child, reaped here
        self.zygote = zygote                # or a child of the zygote, reaped there on our word
        self.orphan = False                 # not our child (its zygote died, or adopted): exit status unknown
        self.adopted = False                # started by an earlier incarnation of the manager
        self.reaped = False                 # gone for good (its pid may be reused from now on)
        self.pid = pid
        self.pidfd = pidfd
        self.started = started              # time.time() when spawned
        self.ready = False
        self.stopping = False               # set before any stop signal: the exit is intentional
        self.exit_info: Optional[ExitInfo] = None
        self.cond = threading.Condition()
        # the ROS nodes it serves, as found at the master by the ports it listens on (an anonymous node
        # included): the ones a restarted master gets back from the ER Manager
        self.nodes: List[str] = []

    @property
    def alive(self) -> bool:
        return self.exit_info is None

    @property
    def state(self) -> str:
        if self.exit_info is not None:
            return 'exited'
        if self.stopping:
            return 'stopping'
        return 'running' if self.ready else 'starting'

    def snapshot(self) -> dict:
        info = self.exit_info
        return {
            'pid': self.pid, 'label': self.spec.label, 'command': self.spec.command,
            'log_path': self.spec.log_path, 'node_names': list(self.spec.node_names),
            'started': self.started, 'uptime': (info.when if info else time.time()) - self.started,
            'state': self.state, 'returncode': info.returncode if info else None,
            'preloaded': self.zygote is not None, 'adopted': self.adopted, 'nodes': list(self.nodes),
        }


ReadyCheck = Callable[[ManagedProcess], bool]
ExitCallback = Callable[[ManagedProcess, ExitInfo], None]


class ProcessSupervisor:
    """Owns child processes from start to reaping.

    ``on_exit(proc, info)`` runs on a dedicated callback thread for every child
    that exits *without* having been asked to (crash, signal from elsewhere,
    or exit 0 while still held). A slow callback never delays reaping.
    """

    def __init__(self, on_exit: Optional[ExitCallback] = None, *, sigint_grace: float = 3.0,
                 sigterm_grace: float = 2.0, death_signal: int = signal.SIGKILL, tail_lines: int = 20,
                 preload_modules: Optional[list] = None, preload_log: str = '', preload_env: Optional[dict] = None,
                 preload_ready_timeout: float = 30.0, leash=None):
        self.on_exit = on_exit
        self.sigint_grace = sigint_grace
        self.sigterm_grace = sigterm_grace
        self.death_signal = int(death_signal)
        self.tail_lines = tail_lines
        self.leash = leash                                   # told of every child; see leash.py
        self._lock = threading.Lock()
        self._procs: dict[int, ManagedProcess] = {}          # pidfd -> process, while not reaped
        self._all: dict[int, ManagedProcess] = {}            # key -> process, until forgotten
        self._closed = False
        self._wake_r, self._wake_w = os.pipe2(os.O_CLOEXEC | os.O_NONBLOCK)
        self._spawn_q: queue.Queue = queue.Queue()
        self._callbacks: queue.Queue = queue.Queue()
        self._recent_exits: deque = deque(maxlen=64)
        self._zprocs: dict[int, ManagedProcess] = {}         # pid -> child of the zygote, until its exit is read
        self._zreaping: dict[int, ManagedProcess] = {}       # pid -> exited child of the zygote, until reaped
        self._zygote: Optional[Zygote] = None                # None: plain spawning only
        self.preload_ready_timeout = preload_ready_timeout
        if preload_modules is not None:
            self._zygote = Zygote(preload_modules, env=dict(os.environ if preload_env is None else preload_env),
                                  log_path=preload_log or os.path.join('/tmp', 'temoto_er_zygote-%d.log' % os.getpid()))
            self._spawn_q.put(('start-zygote', None))
        self._spawner = threading.Thread(target=self._spawn_loop, name='er-spawner', daemon=True)
        self._reaper = threading.Thread(target=self._reap_loop, name='er-reaper', daemon=True)
        self._notifier = threading.Thread(target=self._callback_loop, name='er-exit-callbacks', daemon=True)
        self._spawner.start()
        self._reaper.start()
        self._notifier.start()

    # -- starting ------------------------------------------------------------------------------

    def start(self, spec: ProcessSpec) -> ManagedProcess:
        """Spawn the child (on the spawner thread) and return at once; see :meth:`wait_ready`."""
        if self._closed:
            raise SupervisorError('the process supervisor is shut down')
        fut: Future = Future()
        self._spawn_q.put((spec, fut))
        # a spawn takes milliseconds, or the zygote's imports at most: a spawner stuck beyond that would hold
        # every load of the manager for ever, silently (the chaos history of seed 17 twice had an ER Manager
        # that answered no load after a restart, and left no trace of where it hung)
        bound = self.preload_ready_timeout + SPAWN_SLACK_S
        try:
            return fut.result(timeout=bound)
        except FutureTimeout:
            fut.add_done_callback(self._stop_abandoned)
            why = 'the process spawner did not start %s within %.1f s' % (spec.command, bound)
            _log.error('%s; every thread\'s stack follows', why)
            # in a node, its watchdog restarts the manager, whose next incarnation adopts what runs; elsewhere
            # (a test, a tool) the caller is told
            if not watchdog.wedged(why):
                faulthandler.dump_traceback(all_threads=True)
            raise SpawnerStuck('the process spawner did not start %s within %.1f s: it is stuck (the '
                                  'stacks are in the manager\'s log)' % (spec.command, bound)) from None

    def _stop_abandoned(self, fut: Future) -> None:
        """A spawn whose caller gave up on it: what it started is stopped, not left running for nobody."""
        if fut.exception() is None:
            threading.Thread(target=self._stop_quietly, args=(fut.result(),), name='er-stop-abandoned',
                             daemon=True).start()

    def _spawn_loop(self) -> None:
        while True:
            item = self._spawn_q.get()
            if item is None:
                return
            spec, fut = item
            if spec == 'start-zygote':
                self._start_zygote()
                continue
            try:
                fut.set_result(self._spawn(spec))
            except BaseException as e:        # the caller sees it through the future
                fut.set_exception(e)

    def _start_zygote(self) -> None:
        """On the spawner thread: the zygote dies with it (SIGKILL), whatever ``death_signal`` says."""
        try:
            self._zygote.start(die_with=os.getpid())
            os.write(self._wake_w, b'x')      # let the reaper select on its exit reports
            _log.info('preload zygote pid %d started: importing %s (log %s)', self._zygote.pid,
                      ', '.join(self._zygote.modules), self._zygote.log_path)
        except ZygoteError as e:
            self._drop_zygote('it could not start: %s' % e)

    def _usable_zygote(self, spec: ProcessSpec) -> Optional[Zygote]:
        z = self._zygote
        if z is None or not spec.preloadable or not z.compatible(spec.env):
            return None
        if not z.ready:
            try:
                info = z.wait_ready(self.preload_ready_timeout)
            except ZygoteError as e:
                self._drop_zygote(str(e))
                return None
            for module, error in sorted(info.get('failed', {}).items()):
                _log.warning('preload zygote: cannot import %s (%s); nodes import it themselves', module, error)
            _log.info('preload zygote pid %d ready', z.pid)
        return z

    def _drop_zygote(self, why: str) -> None:
        """Plain spawning from now on; the zygote's live children are watched through their pidfds."""
        with self._lock:
            z, self._zygote = self._zygote, None
            if z is None:
                return
            orphans = list(self._zprocs.values())
            self._zprocs.clear()
            for proc in orphans:
                proc.orphan = True
                self._procs[proc.pidfd] = proc
            exited = list(self._zreaping.values())
            self._zreaping.clear()
        for proc in exited:                   # init reaps them now
            self._mark_reaped(proc)
        _log.warning('preload zygote (pid %d) is not used any more: %s. Python nodes start plainly from now on'
                     '%s', z.pid, why, ' (%d of its children are still watched)' % len(orphans) if orphans else '')
        os.write(self._wake_w, b'x')
        threading.Thread(target=z.close, name='er-zygote-close', daemon=True).start()

    def _spawn(self, spec: ProcessSpec) -> ManagedProcess:
        os.makedirs(os.path.dirname(spec.log_path) or '.', exist_ok=True)
        with open(spec.log_path, 'ab', buffering=0) as log:
            log.write(('[temoto_er_manager] %s $ %s\n' % (time.strftime('%Y-%m-%d %H:%M:%S'),
                                                          spec.command)).encode())
            zygote = self._usable_zygote(spec)
            if zygote is not None:
                proc = self._spawn_from_zygote(zygote, spec, log.fileno())
                if proc is not None:
                    return proc
            options = dict(env=spec.env, cwd=spec.cwd, stdin=subprocess.DEVNULL, stdout=log,
                           stderr=subprocess.STDOUT, close_fds=True, start_new_session=True)
            ignored = [sig for sig in _STOP_SIGNALS if signal.getsignal(sig) is signal.SIG_IGN]
            try:
                if self.death_signal or ignored:
                    # the kernel sends the death signal when the thread that forked the child exits: this one
                    popen = popen_dying_with_this_thread(spec.argv, self.death_signal, ignored, **options)
                else:
                    # nothing to do between fork and exec, so no Python runs there (a manager with a journal:
                    # its leash outlives it instead). process_group.popen_dying_with_this_thread says why
                    popen = subprocess.Popen(spec.argv, **options)
            except OSError as e:
                raise SupervisorError('cannot start %s: %s' % (spec.command, e.strerror or e)) from e
        started = time.time()
        pidfd = os.pidfd_open(popen.pid)
        proc = ManagedProcess(spec, popen.pid, pidfd, started, popen=popen)
        with self._lock:
            self._procs[pidfd] = proc
            self._all[proc.key] = proc
        os.write(self._wake_w, b'x')          # let the reaper select on the new pidfd
        self._leash_watch(proc)
        _log.info('started pid %d: %s (log %s)', proc.pid, spec.command, spec.log_path)
        return proc

    def _leash_watch(self, proc: ManagedProcess) -> None:
        if self.leash is not None:
            start = start_ticks(proc.pid)
            if start is not None:             # None: it died already, and the reaper reports it
                self.leash.watch(proc.pid, start)

    def adopt(self, spec: ProcessSpec, pid: int, start: int, started: float) -> Optional[ManagedProcess]:
        """Watch a process that an earlier incarnation of the manager started; None if it is gone.

        ``start`` is its start time in clock ticks (:func:`start_ticks`), checked before and after the pidfd
        is opened, so a pid that was reused meanwhile is never adopted. The adopted process is not this
        manager's child: its exit is seen through the pidfd, but its exit status is unknown (init reaps it).
        """
        if self._closed or start_ticks(pid) != start:
            return None
        try:
            pidfd = os.pidfd_open(pid)
        except OSError:
            return None
        if start_ticks(pid) != start:         # it died, and the pid was maybe reused, before the open
            os.close(pidfd)
            return None
        proc = ManagedProcess(spec, pid, pidfd, started)
        proc.orphan = proc.adopted = proc.ready = True
        with self._lock:
            self._procs[pidfd] = proc
            self._all[proc.key] = proc
        os.write(self._wake_w, b'x')
        if self.leash is not None:
            self.leash.watch(pid, start)
        _log.info('adopted pid %d: %s', pid, spec.command)
        return proc

    def _spawn_from_zygote(self, zygote: Zygote, spec: ProcessSpec, log_fd: int) -> Optional[ManagedProcess]:
        """Fork ``spec`` from the zygote; None (and the zygote dropped) if it cannot."""
        with self._lock:                      # the reaper looks the pid up under this lock: register first
            try:
                pid = zygote.spawn(spec.argv, spec.env, spec.cwd, log_fd, self.death_signal)
            except ZygoteError as e:
                failure = str(e)
            else:
                # the zygote reaps the child only on our word, so the pid is still this child's
                pidfd = os.pidfd_open(pid)
                proc = ManagedProcess(spec, pid, pidfd, time.time(), zygote=zygote)
                self._zprocs[pid] = proc
                self._all[proc.key] = proc
                failure = None
        if failure is not None:
            self._drop_zygote(failure)
            return None
        self._leash_watch(proc)
        _log.info('started pid %d from the preload zygote: %s (log %s)', pid, spec.command, spec.log_path)
        return proc

    def wait_ready(self, proc: ManagedProcess, check: Optional[ReadyCheck], timeout: float,
                   interval: float = 0.02) -> None:
        """Block until ``check(proc)`` is true, the child exits, it is stopped, or ``timeout``.

        ``check`` is polled every ``interval`` (the ROS master has no push API for
        registrations); the child's exit or a stop wakes the wait at once, so a
        node that dies while starting fails the load immediately. Without
        ``check`` the process is ready when it is still alive after ``timeout``
        (a settle time).
        """
        self.wait_all_ready([proc], check, timeout, interval)

    def wait_all_ready(self, procs: list[ManagedProcess], check: Optional[ReadyCheck], timeout: float,
                       interval: float = 0.02) -> None:
        """:meth:`wait_ready` for processes that form one resource: all must become ready.

        Any one's exit or stop ends the wait with its error (checked before every
        poll, so within ``interval``; the first pending process's exit wakes the
        wait at once), also for a process that was already ready.
        """
        deadline = time.monotonic() + timeout
        pending = list(procs)
        while True:
            for p in procs:
                self._raise_if_gone(p)
            if check is not None:
                still = []
                for p in pending:
                    try:
                        ok = check(p)
                    except Exception as e:    # a flaky look-up is "not yet"
                        _log.debug('ready check for pid %d failed: %s', p.pid, e)
                        ok = False
                    if not (ok and self._mark_ready(p)):
                        still.append(p)
                pending = still
                if not pending:
                    for p in procs:           # one may have died after it was marked ready
                        self._raise_if_gone(p)
                    return
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                if check is None and all(self._mark_ready(p) for p in procs):
                    return
                for p in procs:
                    self._raise_if_gone(p)
                late = pending[0]
                raise ReadyTimeout('process %d (%s) did not become ready within %.1f s'
                                   % (late.pid, late.spec.label or late.spec.command, timeout))
            first = pending[0]
            with first.cond:
                first.cond.wait_for(lambda: not first.alive or first.stopping,
                                    timeout=min(interval, remaining) if check is not None else
                                    (remaining if len(procs) == 1 else min(interval, remaining)))

    @staticmethod
    def _raise_if_gone(proc: ManagedProcess) -> None:
        with proc.cond:
            if proc.stopping:
                raise StartCancelled('process %d (%s) was stopped while it was starting'
                                     % (proc.pid, proc.spec.label or proc.spec.command))
            if not proc.alive:
                info = proc.exit_info
                raise ProcessExitedEarly('process %d (%s) %s before it was ready; last output:\n%s'
                                         % (proc.pid, info.command, info.reason, info.log_tail), info)

    @staticmethod
    def _mark_ready(proc: ManagedProcess) -> bool:
        with proc.cond:
            if proc.alive and not proc.stopping:
                proc.ready = True
                proc.cond.notify_all()
                return True
            return False

    # -- watching ------------------------------------------------------------------------------

    def _reap_loop(self) -> None:
        while True:
            with self._lock:
                fds = list(self._procs)
                zygote = self._zygote
            zfd = zygote.events_fd if zygote is not None else -1
            if zfd >= 0:
                fds.append(zfd)
            try:
                readable, _, _ = select.select([self._wake_r] + fds, [], [])
            except ValueError:                # the zygote's socket closed under us: rebuild the set
                continue
            except OSError as e:              # a pidfd closed under us by a race: rebuild the set
                if e.errno in (errno.EBADF, errno.EINTR):
                    continue
                raise
            if self._wake_r in readable:
                try:
                    while os.read(self._wake_r, 4096):
                        pass
                except BlockingIOError:
                    pass
                if self._closed and not self._procs:
                    return
            for fd in readable:
                try:
                    if fd == zfd:
                        self._zygote_exits(zygote)
                    elif fd != self._wake_r:
                        self._reap(fd)
                except Exception:             # never seen; the reaper must outlive any one process
                    _log.exception('reaping (fd %d) failed', fd)

    def _reap(self, pidfd: int) -> None:
        with self._lock:
            proc = self._procs.pop(pidfd, None)
        if proc is None:
            return
        # Before reaping: while the dead leader is a zombie, its pid (and so its group id) cannot be
        # reused, so the group can be signalled safely. pid_max is 32768 here and wraps within minutes:
        # a group id signalled after the reap may already belong to somebody else's new session.
        if proc.adopted:
            # init reaps it, maybe already: its group id may be reused; never signal it
            self._record_exit(proc, -int(signal.SIGKILL), 'exited (exit status unknown: it was adopted after a '
                              'restart of the manager, so it is not the manager\'s child)')
            return
        if proc.orphan:
            # its zygote died, so init reaps it, maybe already: its group id may be reused; never signal it
            self._record_exit(proc, -int(self.death_signal or signal.SIGKILL),
                              'died after its preload zygote died (exit status unknown)')
            return
        if group_members(proc.pid, exclude=proc.pid):
            self._kill_members_of_dead_leader(proc.pid)
        self._record_exit(proc, None)

    def _zygote_exits(self, zygote: Zygote) -> None:
        """Exits the zygote reported: record each (its group cleaned first), then let the zygote reap it."""
        events, gone = zygote.read_events()
        for kind, pid, rc in events:
            if kind == 'reaped':
                with self._lock:
                    proc = self._zreaping.pop(pid, None)
                if proc is not None:
                    self._mark_reaped(proc)
                continue
            with self._lock:
                proc = self._zprocs.pop(pid, None)
                if proc is not None:
                    self._zreaping[pid] = proc
            if proc is not None:
                # the zombie holds the pid and group id until we ack: the same rule as _reap
                if group_members(pid, exclude=pid):
                    self._kill_members_of_dead_leader(pid)
                self._record_exit(proc, rc)
            zygote.ack(pid)                   # after the exit is recorded: stop() never signals it again
        if gone:
            self._drop_zygote('it exited (%s); its output is in %s' % (zygote.exit_text(), zygote.log_path))

    @staticmethod
    def _mark_reaped(proc: ManagedProcess) -> None:
        with proc.cond:
            proc.reaped = True
            proc.cond.notify_all()

    def _record_exit(self, proc: ManagedProcess, rc: Optional[int], detail: str = '') -> None:
        with proc.cond:                       # stop() signals the group only under this lock
            if rc is None:
                rc = proc.popen.wait()        # already dead: returns at once and reaps
            if proc.zygote is None or proc.orphan:
                proc.reaped = True            # by us, or by init
            os.close(proc.pidfd)
            info = ExitInfo(pid=proc.pid, returncode=rc, command=proc.spec.command,
                            log_tail=read_tail(proc.spec.log_path, self.tail_lines),
                            intentional=proc.stopping, when=time.time(), detail=detail)
            proc.exit_info = info
            proc.cond.notify_all()
        self._recent_exits.append(info)
        if self.leash is not None:
            self.leash.forget(proc.pid)
        if info.intentional:
            _log.info('pid %d stopped: %s', proc.pid, info.reason)
        else:
            _log.warning('pid %d %s: %s', proc.pid, info.reason, proc.spec.command)
            # also a child that exits before it is ready: wait_ready reports that to the loader,
            # and the consumer-facing owner decides what a failure during loading means.
            self._callbacks.put((proc, info))

    def _kill_members_of_dead_leader(self, pgid: int) -> None:
        """SIGKILL what the dead leader left in its group (bounded; the zombie holds the id meanwhile)."""
        deadline = time.monotonic() + 2.0
        while group_members(pgid, exclude=pgid) and time.monotonic() < deadline:
            self._killpg(pgid, signal.SIGKILL)
            time.sleep(0.005)

    def _callback_loop(self) -> None:
        while True:
            item = self._callbacks.get()
            if item is None:
                return
            proc, info = item
            if self.on_exit is not None:
                try:
                    self.on_exit(proc, info)
                except Exception:
                    _log.exception('exit callback for pid %d failed', proc.pid)

    # -- stopping ------------------------------------------------------------------------------

    def stop(self, proc: ManagedProcess, sigint_grace: Optional[float] = None,
             sigterm_grace: Optional[float] = None) -> ExitInfo:
        """Stop the child's group: SIGINT, then SIGTERM, then SIGKILL; return once it is reaped.

        Safe to call twice and on an exited process (returns its exit info).
        """
        sigint_grace = self.sigint_grace if sigint_grace is None else sigint_grace
        sigterm_grace = self.sigterm_grace if sigterm_grace is None else sigterm_grace
        with proc.cond:
            if proc.exit_info is not None and not proc.stopping:
                # already dead on its own, reported, and its group cleaned before the reap;
                # its group id may belong to another process by now: never signal it again
                return proc.exit_info
            proc.stopping = True
            proc.cond.notify_all()            # a wait_ready in progress gives up now

        def send(sig: int) -> None:
            with proc.cond:
                # under the lock: the leader cannot be reaped meanwhile (by us, or by the zygote, which waits
                # for our word); an orphan of a dead zygote that has exited may be reaped by init already
                if proc.exit_info is None and not (proc.orphan and _pidfd_readable(proc.pidfd)):
                    self._killpg(proc.pid, sig)

        def ended(timeout: float) -> bool:
            with proc.cond:
                return proc.cond.wait_for(lambda: proc.exit_info is not None, timeout=timeout)
        escalate(stop_stages(sigint_grace, sigterm_grace), send, ended)
        with proc.cond:
            if proc.exit_info is None:        # SIGKILL + 5 s and still not reaped: never seen; be loud
                raise SupervisorError('process %d did not exit after SIGKILL' % proc.pid)
            # a child of the zygote is reaped there once we recorded its exit: return when it is gone
            if not proc.cond.wait_for(lambda: proc.reaped, timeout=5.0):
                _log.warning('pid %d: its exit is recorded but the zygote has not reaped it yet', proc.pid)
            return proc.exit_info

    @staticmethod
    def _killpg(pgid: int, sig: int) -> bool:
        try:
            os.killpg(pgid, sig)
            return True
        except ProcessLookupError:
            return False
        except PermissionError:               # pid reused by someone else's group: not ours
            return False

    def forget(self, proc: ManagedProcess) -> None:
        """Drop an exited process from the listing."""
        with self._lock:
            if proc.exit_info is not None:
                self._all.pop(proc.key, None)

    def processes(self) -> list[ManagedProcess]:
        with self._lock:
            return list(self._all.values())

    def shutdown(self) -> None:
        """Stop every child (in parallel) and end the supervisor's threads."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            procs = [p for p in self._all.values() if p.alive]
        threads = [threading.Thread(target=self._stop_quietly, args=(p,), daemon=True) for p in procs]
        for t in threads:
            t.start()
        for t in threads:
            t.join(self.sigint_grace + self.sigterm_grace + 10.0)
        self._spawn_q.put(None)
        self._spawner.join(5.0)
        with self._lock:
            zygote, self._zygote = self._zygote, None
        if zygote is not None:
            zygote.close()
        self._callbacks.put(None)
        os.write(self._wake_w, b'x')
        self._reaper.join(2.0)

    def _stop_quietly(self, proc: ManagedProcess) -> None:
        try:
            self.stop(proc)
        except Exception:
            _log.exception('stopping pid %d failed', proc.pid)
