"""The leash: a child outlives a SIGKILLed ER Manager, but not forever. No ROS in here.

With a journal, the ER Manager starts its children without a death signal, so that a crash of the
manager does not blank every sensor, and its next incarnation adopts them
(:meth:`ProcessSupervisor.adopt`). Something must still stop a child that no manager comes back
for. That is the leash: a small single-threaded process that the manager starts once, in its own
session, and tells about every child it starts (pid and start time).

- While the manager is connected, the leash only listens.
- When the connection breaks (the manager died), it waits up to ``bound`` seconds for a manager to
  connect and claim the children. A claim hands every child that still runs to the new manager, and
  the leash carries on for it.
- If no manager claims them in time, the leash stops them (SIGINT, then SIGTERM, then SIGKILL to each
  group, the leader's start time checked before every signal, so that a reused pid is never
  signalled) and exits.

So a child outlives every manager by at most ``bound`` + ``sigint_grace`` + ``sigterm_grace``
seconds (30 + 3 + 2 by default). A manager that stops cleanly stops its children itself and then
releases the leash, which exits. If the leash dies while the manager runs, the manager starts a new
one and tells it its children again. Not covered: the leash and the manager killed together, with no
manager ever restarted; the children then run until something else stops them.

The address is an abstract Unix socket named after the manager's journal, so the manager that reopens
that journal finds the leash of the one before it, and a second manager on the same journal is refused
(only one owner at a time).

Protocol (``SOCK_SEQPACKET``, one JSON object per packet), manager to leash: ``claim`` (first; the
answer is ``{"children": [[pid, start], ...], "leash": pid}`` or ``{"error": text}``), then
``watch`` (pid, start), ``forget`` (pid) and ``release``.
"""
from __future__ import annotations

import hashlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from typing import Dict, List, Optional, Tuple

from temoto_core.process_group import escalate, group_members, start_ticks, stop_stages

DEFAULT_BOUND = 30.0
MAX_MESSAGE = 1 << 16
_PKG_PARENT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_BOOT = ('import sys; sys.path[0] = %r; from temoto_er_manager.leash import main; sys.exit(main(sys.argv[1:]))'
         % _PKG_PARENT)

Child = Tuple[int, int]       # (pid, start ticks)


class LeashError(RuntimeError):
    """The leash cannot be reached or started, or another manager owns it."""


class LeashOwned(LeashError):
    """Another manager is connected to the leash."""


# in the environment of every child of a manager with a journal: its leash's address. A child the manager
# started but had not yet told its leash about when it died is found by this (the next incarnation stops it)
OWNER_ENV = 'TEMOTO_ER_OWNER'


def address_for(journal_path: str) -> str:
    """The leash's abstract socket name for the manager that keeps ``journal_path``."""
    digest = hashlib.sha1(os.path.abspath(journal_path).encode()).hexdigest()[:20]
    return 'temoto-er-leash-' + digest


def _send(sock: socket.socket, message: dict) -> None:
    sock.send(json.dumps(message).encode())


# -- the leash process ------------------------------------------------------------------------------

class _Leash:
    def __init__(self, listener: socket.socket, bound: float, sigint_grace: float, sigterm_grace: float) -> None:
        self.listener = listener
        self.bound = bound
        self.stages = stop_stages(sigint_grace, sigterm_grace)
        self.children: Dict[int, int] = {}
        self.owner: Optional[socket.socket] = None
        self.owner_pid = None
        self.orphaned_at: Optional[float] = time.monotonic()     # no owner yet: the first must connect in time

    def live_children(self) -> List[Child]:
        return [(pid, start) for pid, start in self.children.items() if start_ticks(pid) == start]

    def serve(self) -> None:
        while True:
            wait = None
            if self.owner is None:
                if self.owner_pid is not None and not self.live_children():
                    log('no owner and no child left: exiting')
                    return
                left = self.orphaned_at + self.bound - time.monotonic()
                if left <= 0:
                    self.stop_children('no ER Manager claimed them within %.0f s' % self.bound)
                    return
                wait = min(left, 1.0)     # also notices children that exit meanwhile
            fds = [self.listener] + ([self.owner] if self.owner is not None else [])
            readable, _, _ = select.select(fds, [], [], wait)
            # the owner first: a manager that died and its successor's claim may arrive together
            if self.owner is not None and self.owner in readable:
                if not self.from_owner():
                    return
            if self.listener in readable:
                self.accept()

    def accept(self) -> None:
        conn, _ = self.listener.accept()
        conn.settimeout(2.0)
        try:
            data = conn.recv(MAX_MESSAGE)
            request = json.loads(data) if data else {}
            if request.get('op') != 'claim':
                _send(conn, {'error': 'the first message must be a claim'})
            elif self.owner is not None:
                _send(conn, {'error': 'another ER Manager (pid %s) owns these children' % self.owner_pid})
            else:
                self.owner, self.owner_pid, self.orphaned_at = conn, request.get('pid'), None
                conn.settimeout(None)
                _send(conn, {'children': self.live_children(), 'leash': os.getpid()})
                self.children = dict(self.live_children())
                log('claimed by pid %s: %d live child(ren)' % (self.owner_pid, len(self.children)))
                return
        except (OSError, ValueError) as err:
            log('refused a connection: %s' % err)
        conn.close()

    def from_owner(self) -> bool:
        """One message of the owner; False when the leash should exit."""
        try:
            data = self.owner.recv(MAX_MESSAGE)
        except OSError:
            data = b''
        if not data:
            self.owner.close()
            self.owner, self.orphaned_at = None, time.monotonic()
            log('the ER Manager (pid %s) is gone; %d child(ren) wait up to %.0f s for a new one'
                % (self.owner_pid, len(self.live_children()), self.bound))
            return True
        message = json.loads(data)
        op = message.get('op')
        if op == 'watch':
            self.children[int(message['pid'])] = int(message['start'])
        elif op == 'forget':
            self.children.pop(int(message['pid']), None)
        elif op == 'release':
            log('released by pid %s' % self.owner_pid)
            return False
        return True

    def stop_children(self, why: str) -> None:
        live = self.live_children()
        log('%s: stopping %d child(ren): %s' % (why, len(live), ' '.join(str(pid) for pid, _ in live)))

        def send(sig: int) -> None:         # every child at once: their graces run side by side
            live[:] = [(pid, start) for pid, start in live if _signal_group(pid, start, sig)]

        def ended(timeout: float) -> bool:
            deadline = time.monotonic() + timeout
            while True:
                live[:] = [(pid, start) for pid, start in live if start_ticks(pid) == start or group_members(pid)]
                if not live or time.monotonic() >= deadline:
                    return not live
                time.sleep(0.02)
        escalate(self.stages, send, ended)


def _signal_group(pid: int, start: int, sig: int) -> bool:
    """Signal the group ``pid`` leads, if it is still that process's; True if anything was signalled."""
    if start_ticks(pid) == start:
        try:
            os.killpg(pid, sig)
            return True
        except (ProcessLookupError, PermissionError):
            return False
    # the leader is gone: while members remain, the group id cannot have been reused
    members = group_members(pid)
    for member in members:
        try:
            os.kill(member, sig)
        except (ProcessLookupError, PermissionError):
            pass
    return bool(members)


def log(text: str) -> None:
    print('[temoto_er_manager leash %d] %s %s' % (os.getpid(), time.strftime('%H:%M:%S'), text), flush=True)


def main(argv: list) -> int:
    """``leash ADDRESS BOUND SIGINT_GRACE SIGTERM_GRACE``; exits 0 at once if another leash has the address."""
    for sig in (signal.SIGINT, signal.SIGHUP, signal.SIGPIPE):
        signal.signal(sig, signal.SIG_IGN)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        listener.bind('\0' + argv[0])
    except OSError as err:
        log('not needed: %s is taken (%s)' % (argv[0], err))
        return 0
    listener.listen(4)
    log('listening on @%s (bound %s s)' % (argv[0], argv[1]))
    _Leash(listener, float(argv[1]), float(argv[2]), float(argv[3])).serve()
    return 0


# -- the manager's handle ------------------------------------------------------------------------------

class Leash:
    """The manager's connection to its leash. :meth:`attach` finds or starts it and claims the children."""

    def __init__(self, address: str, bound: float, sigint_grace: float, sigterm_grace: float, log_path: str,
                 on_restart=None) -> None:
        self.address = address
        self.bound = bound
        self.graces = (sigint_grace, sigterm_grace)
        self.log_path = log_path
        self.on_restart = on_restart          # called with an error text when the leash had to be restarted
        self.leash_pid = 0
        self._popen: Optional[subprocess.Popen] = None
        self._sock: Optional[socket.socket] = None
        self._lock = threading.Lock()
        self._children: Dict[int, int] = {}
        self._closed = False

    def attach(self, timeout: float = 10.0, owned_patience: float = 2.0) -> List[Child]:
        """Claim the leash (starting it if there is none); the children it kept for this manager.

        An owner still connected may be the previous incarnation in its last moment (a warm respawn's
        parent was killed, and the death signal is still on its way to the old node): the claim is
        tried again for ``owned_patience`` before it is refused for good."""
        deadline = time.monotonic() + timeout
        owned_until = time.monotonic() + owned_patience
        started = False
        while True:
            try:
                children = self._claim()
                break
            except (ConnectionRefusedError, FileNotFoundError):
                if not started:
                    self._start()
                    started = True
            except LeashOwned:
                if time.monotonic() > owned_until:
                    raise
            if time.monotonic() > deadline:
                raise LeashError('the leash at @%s did not start within %.0f s (log %s)'
                                 % (self.address, timeout, self.log_path))
            time.sleep(0.01)
        threading.Thread(target=self._watch_connection, name='er-leash', daemon=True).start()
        return children

    def _start(self) -> None:
        os.makedirs(os.path.dirname(self.log_path) or '.', exist_ok=True)
        with open(self.log_path, 'ab', buffering=0) as out:
            # own session and no death signal: it must outlive this manager
            self._popen = subprocess.Popen(
                [sys.executable, '-c', _BOOT, self.address, str(self.bound), str(self.graces[0]),
                 str(self.graces[1])], stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                cwd='/', close_fds=True, start_new_session=True)

    def _claim(self) -> List[Child]:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            sock.settimeout(5.0)
            sock.connect('\0' + self.address)
            _send(sock, {'op': 'claim', 'pid': os.getpid()})
            data = sock.recv(MAX_MESSAGE)
        except (ConnectionRefusedError, FileNotFoundError):
            sock.close()
            raise
        except OSError as err:
            sock.close()
            raise LeashError('the leash at @%s did not answer: %s' % (self.address, err)) from None
        answer = json.loads(data) if data else {'error': 'it closed the connection'}
        if 'error' in answer:
            sock.close()
            raise (LeashOwned if 'owns' in answer['error'] else LeashError)(
                'the leash at @%s refused: %s' % (self.address, answer['error']))
        sock.settimeout(None)
        with self._lock:
            self._sock, self.leash_pid = sock, int(answer['leash'])
            for pid, start in self._children.items():   # after a restart of the leash: tell it again
                _send(sock, {'op': 'watch', 'pid': pid, 'start': start})
        return [(int(pid), int(start)) for pid, start in answer['children']]

    def _watch_connection(self) -> None:
        """Blocks on the socket; the leash closing it means it died: start a new one."""
        while True:
            sock = self._sock
            try:
                data = sock.recv(MAX_MESSAGE)
            except OSError:
                data = b''
            if self._closed:
                return
            if data:
                continue
            self._reap(wait=1.0)
            try:
                self.attach_again()
            except LeashError as err:
                if self.on_restart:
                    self.on_restart('the leash died and could not be restarted: %s' % err)
                return
            if self.on_restart:
                self.on_restart('the leash died; a new one (pid %d) watches the children' % self.leash_pid)

    def attach_again(self) -> None:
        deadline = time.monotonic() + 10.0
        self._start()
        while True:
            try:
                self._claim()
                return
            except (ConnectionRefusedError, FileNotFoundError):
                if time.monotonic() > deadline:
                    raise LeashError('no leash at @%s after a restart' % self.address) from None
                time.sleep(0.01)

    def watch(self, pid: int, start: int) -> None:
        with self._lock:
            self._children[pid] = start
            self._send({'op': 'watch', 'pid': pid, 'start': start})

    def forget(self, pid: int) -> None:
        with self._lock:
            self._children.pop(pid, None)
            self._send({'op': 'forget', 'pid': pid})

    def _send(self, message: dict) -> None:
        try:
            _send(self._sock, message)
        except OSError:
            pass              # the connection watcher restarts the leash and tells it everything again

    def release(self) -> None:
        """Clean shutdown, after this manager stopped its children: the leash exits."""
        with self._lock:
            self._closed = True
            if self._sock is not None:
                self._send({'op': 'release'})
                self._sock.close()
        self._reap(wait=5.0)

    def _reap(self, wait: float = 0.0) -> None:
        popen = self._popen
        if popen is None:
            return
        try:
            popen.wait(wait)
        except subprocess.TimeoutExpired:
            popen.kill()
            popen.wait(5.0)
