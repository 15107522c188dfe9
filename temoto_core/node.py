"""Node lifetime: SIGINT and SIGTERM handled outside signal-handler context.

rospy's own handler runs ``rospy.signal_shutdown`` *inside* the Python signal
handler, that is, on the main thread between two arbitrary bytecodes. If the
main thread is publishing at that moment, it may hold the non-reentrant lock of
a queued publisher connection (``QueuedConnection._lock``, taken in
``write_data``), and the shutdown it runs closes that same connection and takes
that lock again: the node deadlocks, ignores every later SIGINT and SIGTERM,
and only SIGKILL ends it. A driver publishing at 25 Hz hit this in CI, and in
about one stop in ten when reproduced under load (faulthandler gave the stack).
``threading.Event.set`` from a handler has the same hazard while the main
thread is in ``Event.wait``.

So the handlers here do nothing in Python: Python's C-level handler writes the
signal number to a wake-up pipe (``signal.set_wakeup_fd``), and a daemon thread
reads it and calls back from ordinary thread context, where taking any lock is
safe. ``init_node`` hands the signal to the main thread, whose ``spin()`` or
``while ok():`` loop then runs rospy's shutdown between two of its own steps.
"""
from __future__ import annotations

import faulthandler
import http.client
import os
import signal
import sys
import threading
import time
import xmlrpc.client
from typing import Callable, Iterable

import rosgraph
import rosgraph.names
import rospy

from temoto_core import master_lookup, master_rejoin, params, rospy_internals, watchdog

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _ignore(signum, frame) -> None:
    """Installed as the Python handler so that the wake-up fd is written; the work is done elsewhere."""


def on_signals(callback: Callable[[int], None], signals: Iterable[int] = STOP_SIGNALS) -> threading.Thread:
    """Call ``callback(signum)`` from a daemon thread whenever one of ``signals`` arrives.

    Must be called from the main thread (a rule of ``signal``). The process has
    one wake-up fd, so call this once; signals with no Python handler of their
    own are not reported.
    """
    wanted = frozenset(int(s) for s in signals)
    read_fd, write_fd = os.pipe2(os.O_CLOEXEC)
    os.set_blocking(write_fd, False)             # set_wakeup_fd requires it; a full pipe only drops duplicates
    signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    for s in wanted:
        signal.signal(s, _ignore)

    def relay() -> None:
        while True:
            try:
                data = os.read(read_fd, 64)
            except InterruptedError:
                continue
            if not data:
                return
            for signum in data:
                if signum in wanted:
                    callback(signum)

    thread = threading.Thread(target=relay, name='temoto-signals', daemon=True)
    thread.start()
    return thread


_stop_signal = threading.Event()     # a stop signal arrived; ok() reads it without taking a lock
_wake = threading.Event()            # wakes spin(): a stop signal, or rospy shutting down for another reason
_shut_by_main = threading.Event()    # the main thread has run rospy's shutdown
MAIN_THREAD_GRACE = 2.0              # s the relay waits for the main thread before shutting rospy down itself


def init_node(name: str, **kwargs) -> None:
    """``rospy.init_node`` whose SIGINT/SIGTERM shut rospy down on the main thread, outside any handler.

    The main thread must then run ``spin()`` or a ``while ok():`` loop: either
    runs rospy's shutdown between two of its own steps, where it holds no lock.
    Not from the relay thread, because rospy closes its topics right after
    ``is_shutdown()`` turns true, so a main loop publishing meanwhile would
    raise. A main thread that does not come round within MAIN_THREAD_GRACE
    (blocked in start-up, say) is overtaken: the relay thread shuts rospy down.
    """
    def on_stop(signum: int) -> None:
        _stop_signal.set()
        _wake.set()
        if not _shut_by_main.wait(MAIN_THREAD_GRACE):
            rospy.signal_shutdown('signal %d (main thread busy)' % signum)
    # before init_node: the node is visible at the master before init_node returns, and a supervisor may
    # stop it from then on (Python's default SIGINT handler would raise KeyboardInterrupt mid-registration)
    on_signals(on_stop)
    # `kill -USR1 <pid>` writes every thread's Python stack to stderr (the node's log): how a wedged node is
    # diagnosed without a debugger; it runs in C, so it works even when the node is deadlocked
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    kwargs['disable_signals'] = True
    clear_stale_registration(name, kwargs.get('anonymous', False))
    rospy_internals.install_bounded_handshake()   # one silent peer must not hold up every connection to this node
    rospy_internals.install_shutdown_guard()      # nor may a master's shutdown meant for a dead node on its port
    rospy.init_node(name, **kwargs)
    rospy.on_shutdown(_wake.set)
    after_init_node()


def run_node(name: str, make: Callable[[], object]) -> None:
    """A motion node's ``main``: :func:`init_node`, then ``make()`` (its constructor reads its parameters and its
    robot description) and the node's ``spin()``. A ``ValueError`` from ``make`` is a bad parameter or description:
    said, naming it, and the process exits 2, which the ER Manager reports to whoever started it."""
    init_node(name)
    try:
        node = make()
    except ValueError as err:
        rospy.logerr('%s: %s', name, err)
        raise SystemExit(2)
    node.spin()


def after_init_node() -> None:
    """What every TeMoto node sets up right after ``rospy.init_node``, this module's ``init_node`` or its
    own (the RViz host's and the action engine's, which handle their signals themselves)."""
    prime_log_parameter()
    rospy_internals.install_shutdown_guard()   # here too for the nodes that call rospy.init_node themselves
    # a node whose own locks wedge kills itself with its stacks written, rather than answer nothing for good
    watchdog.install(params.seconds('watchdog_bound', watchdog.DEFAULT_BOUND_S))
    master_rejoin.ensure_started()      # a master that restarts gets this node's registrations back


def prime_log_parameter() -> None:
    """Read, once, the one parameter rospy's logging reads, and keep it in rospy's parameter cache.

    Every rospy log call reads ``/rosout_disable_topics_generation`` through the
    parameter cache, and rospy caches an *unset* parameter as missing: while it
    is unset (as it is unless someone sets it), every log call asks the master
    again, with no timeout. A warning logged while the master is out of reach
    (its host cut off: a partition is exactly when a registrar warns) then
    blocks the thread that logs it, the one that was to report the partition,
    for as long as TCP retries, many minutes. Here the value (False when unset,
    as rospy reads it) is cached once; rospy's parameter subscription keeps it
    current if someone sets it later.
    """
    key = '/rosout_disable_topics_generation'
    rospy_internals.cache_param(key, rospy.get_param_cached(key, False))


def clear_stale_registration(name: str, anonymous: bool = False) -> None:
    """Before registering: remove what a dead earlier process under this node's name left at the master.

    A respawned node registers under the name of one that was killed, and the master then sends
    ``shutdown`` to the old URI. If the dead node's port has been given to another process meanwhile,
    that process is shut down instead of nobody (``master_lookup.cleanup_dead_node``).
    """
    if anonymous:
        return
    mappings = rosgraph.names.load_mappings(sys.argv)
    full = rosgraph.names.ns_join(rosgraph.names.get_ros_namespace(argv=sys.argv), mappings.get('__name', name))
    try:
        gone = master_lookup.cleanup_dead_node(rosgraph.get_master_uri(), full)
    except (OSError, xmlrpc.client.Error, http.client.HTTPException):
        return                            # no master yet: rospy waits for it, and nothing stale can be there
    if gone:
        sys.stderr.write('%s: removed %d registration(s) a dead earlier %s left at the master\n'
                         % (full, gone, full))


def ok() -> bool:
    """The condition of a node's loops: False once rospy is shut down or a stop signal arrived.

    On the main thread, the first call after a stop signal runs rospy's whole
    shutdown there before returning False. On any other thread it only reads:
    rospy sets its shutdown flag first and closes its topics after, so a
    shutdown run by a side thread (a driver's diagnostics loop, say) lands
    between the main loop's ``ok()`` and its ``publish()``, which then raises
    "publish() to a closed topic" and the node exits 1 on a plain SIGINT (CI, once).
    """
    if threading.current_thread() is not threading.main_thread():
        return not (_stop_signal.is_set() or rospy_internals.is_shutdown_requested())
    if _stop_signal.is_set() and not rospy_internals.is_shutdown_requested():
        rospy.signal_shutdown('stop signal')
        _shut_by_main.set()
    return not rospy.is_shutdown()


def stop_requested() -> bool:
    """True once a stop signal arrived, rospy still up until the main thread's next ``ok()``. A main loop with
    last words (a controller that gives its arm back) leaves on this, says them, then calls ``ok()``; the
    relay thread shuts rospy down itself after ``MAIN_THREAD_GRACE`` if the words take longer."""
    return _stop_signal.is_set()


def spin() -> None:
    """Block the main thread until rospy shuts down; on a stop signal, shut it down here first.

    Wakes at once (``rospy.spin`` polls every 0.5 s). The 1 s re-check only
    covers a shutdown that was under way before init_node's hook was added.
    """
    while ok():
        if _wake.is_set():    # shut down from another thread: ok() turns False once its first half is done
            time.sleep(0.01)
        else:
            _wake.wait(1.0)
