"""The node watchdog: a node whose own machinery wedges kills itself, loudly, instead of answering nothing.

Why: a manager that stops serving while it looks alive (its process runs, its XML-RPC answers pings, its
services accept connections) is the one failure nothing outside can tell from a slow one. Its consumers'
calls time out one by one, and what it should release is never released. The chaos history of seed 17
found the robot's ER Manager like this twice, each time within a second of a restart, and it left no
trace of where it hung.

A lock held for good is how such a wedge looks from inside. So one thread tries each lock the node
cannot serve without (its registrars' locks, and rospy logging's, which every thread takes), once every
``period``, and waits at most ``bound`` seconds for it. A lock that cannot be taken within ``bound``
means the node is wedged. A part that knows it is stuck says so too (:func:`wedged`: the ER Manager's
process spawner does).

A wedged node writes why, and every thread's stack, to stderr (its log; not through rospy, which may be
the part that hangs). Then it SIGKILLs itself:

- a journaled manager is forked again at once by its warm-respawn parent (``warm_respawn.py``) and takes its
  registry back from the journal;
- its consumers see what any crash of it shows them.

So a silent wedge becomes a crash that is reported and recovered, and the stacks say where it hung.
"""
import faulthandler
import logging
import os
import signal
import threading
import time
from typing import Callable, Dict, Optional

# no watched lock is held this long by a node that works: the registry's longest hold measured is 0.8 s (ten
# thousand resources and a thousand new consumers at once). A consumer's call deadline is 15 s by default,
# so a wedged owner is restarted before most calls to it expire
DEFAULT_BOUND_S = 10.0
DEFAULT_PERIOD_S = 1.0
RETRY_S = 1.0


def _die(why: str) -> None:
    os.kill(os.getpid(), signal.SIGKILL)


class Watchdog:
    """Tries each watched lock once per ``period``; one not taken within ``bound`` seconds calls
    :meth:`wedged`, which writes the stacks and calls ``on_wedged`` (by default: SIGKILL this process)."""

    def __init__(self, bound: float = DEFAULT_BOUND_S, period: float = DEFAULT_PERIOD_S,
                 on_wedged: Callable[[str], None] = _die) -> None:
        if not 0 < period <= bound:
            raise ValueError('watchdog: the period (%r s) must be positive and not longer than the bound (%r s)'
                             % (period, bound))
        self.bound, self.period = bound, period
        self._on_wedged = on_wedged
        self._locks: Dict[str, object] = {}
        self._guard = threading.Lock()          # guards _locks only; never held while a watched lock is tried
        self._stop = threading.Event()
        self._fired = threading.Event()
        self._thread = threading.Thread(target=self._run, name='temoto-watchdog', daemon=True)

    def watch(self, name: str, lock) -> None:
        """Watch ``lock`` (anything with ``acquire(timeout=...)`` and ``release()``) under ``name``."""
        with self._guard:
            self._locks[name] = lock

    def unwatch(self, name: str, lock=None) -> None:
        """Stop watching ``name``; with ``lock``, only while ``name`` still stands for that lock (a registrar
        made again under the same name before the old one shut down keeps its watch)."""
        with self._guard:
            if lock is None or self._locks.get(name) is lock:
                self._locks.pop(name, None)

    def start(self) -> 'Watchdog':
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def check(self) -> str:
        """Try every watched lock once: '' if each was taken within the bound, else why the node is wedged."""
        with self._guard:
            locks = list(self._locks.items())
        for name, lock in locks:
            started = time.monotonic()
            # the second try: a process SIGSTOPped longer than the bound (a debugger, an operator) times the
            # first wait out as it resumes, before the thread that held the lock could run again
            if not (lock.acquire(timeout=self.bound) or lock.acquire(timeout=min(RETRY_S, self.bound))):
                return '%s was not free for %.1f s' % (name, time.monotonic() - started)
            lock.release()
        return ''

    def wedged(self, why: str) -> None:
        """The node cannot serve any more: say why and where every thread is, then ``on_wedged`` (once)."""
        if self._fired.is_set():
            return
        self._fired.set()
        try:
            os.write(2, ('[temoto watchdog] pid %d is wedged: %s; every thread\'s stack follows, then it kills '
                         'itself so that it is restarted\n' % (os.getpid(), why)).encode())
            faulthandler.dump_traceback(all_threads=True)
        finally:
            self._on_wedged(why)

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            why = self.check()
            if why and not self._stop.is_set():
                self.wedged(why)
                return


_installed: Optional[Watchdog] = None


def install(bound: float = DEFAULT_BOUND_S, period: float = DEFAULT_PERIOD_S) -> Optional[Watchdog]:
    """Start this process's watchdog, watching logging's locks (once rospy has set its handlers up).
    ``bound`` 0 turns it off. Returns it (None when off)."""
    global _installed
    if _installed is not None or bound <= 0:
        return _installed
    dog = Watchdog(bound, min(period, bound))
    dog.watch('the logging module lock', logging._lock)      # every getLogger() takes it: rospy's log calls do
    for logger in (logging.getLogger(), logging.getLogger('rosout')):
        for handler in logger.handlers:
            if handler.lock is not None:
                dog.watch('the lock of log handler %s' % type(handler).__name__, handler.lock)
    _installed = dog.start()
    return dog


def watch(name: str, lock) -> None:
    """Watch ``lock`` if this process has a watchdog (nodes do; a test process need not)."""
    if _installed is not None:
        _installed.watch(name, lock)


def unwatch(name: str, lock=None) -> None:
    if _installed is not None:
        _installed.unwatch(name, lock)


def wedged(why: str) -> bool:
    """A part that knows it is stuck for good: the node is wedged. False (and nothing done) if this process
    has no watchdog: the caller reports it its own way."""
    if _installed is None:
        return False
    _installed.wedged(why)
    return True
