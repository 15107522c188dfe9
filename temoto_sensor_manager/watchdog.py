"""Data watchdog: first-message detection and stall detection for held sensors.

A driver whose cable is pulled may stay alive and publish nothing; the ER
Manager cannot see that. Each watched topic records the arrival time of its
last message, and the gap since the one before (``arrivals.py``: the limit
follows the topic's own rhythm, within the catalogue's). One
thread keeps a heap of deadlines and sleeps until the earliest: if a message
arrived meanwhile the entry is pushed again to ``last + limit``, otherwise the
topic has been silent for its whole limit and the stall callback runs. So the
thread wakes about once per limit per topic, and a stall is reported at most a
scheduling delay after the limit, never a poll period later.
"""
import heapq
import itertools
import threading
import time
from typing import Callable, List, Optional

import rospy

from temoto_sensor_manager.arrivals import ArrivalModel


# seconds: the longest an adaptive probe goes unchecked (its limit may have shrunk since the last look)
ADAPTIVE_RECHECK = 0.1


class TopicProbe:
    """An ``AnyMsg`` subscription that remembers when its topic last carried a message, and its rhythm."""

    def __init__(self, topic: str, limit: float, on_first: Optional[Callable[[], None]] = None,
                 rate: float = 0.0, adaptive: bool = True) -> None:
        """``limit``: the catalogue's silence limit (0: not watched); with ``adaptive``, the most the
        limit measured from the topic's own rhythm may be (``arrivals.py``). ``rate``: nominal Hz (0:
        unknown)."""
        self.topic = topic
        self.limit = limit                   # seconds of silence that count as a stall at most; 0: not watched
        self.nominal_period = 1.0 / rate if rate > 0 else 0.0
        self.arrivals = ArrivalModel() if adaptive else None
        self.last = 0.0                      # time.monotonic() of the last message
        self.count = 0
        self.max_gap = 0.0                   # longest time between two messages seen (what a limit must exceed)
        self.first = threading.Event()
        self.armed = False
        self.quiet_from = 0.0                # silence counts from max(last, quiet_from): see Watchdog.arm
        self.owner = None                    # set by the watchdog user (what stalled)
        self._on_first = on_first
        self._sub = rospy.Subscriber(topic, rospy.AnyMsg, self._on_msg, queue_size=1, tcp_nodelay=True)

    def _on_msg(self, _msg) -> None:
        now = time.monotonic()
        if self.count:
            gap = now - self.last
            if gap > self.max_gap:
                self.max_gap = gap
            if self.arrivals is not None and self.armed:    # a driver's start-up is not its rhythm
                self.arrivals.add(gap)
        self.last = now
        self.count += 1
        if not self.first.is_set():
            self.first.set()
            if self._on_first is not None:
                self._on_first()

    def current_limit(self) -> float:
        """The silence that counts as a stall now."""
        if self.arrivals is None:
            return self.limit
        return self.arrivals.limit(self.limit, self.nominal_period)

    def describe_limit(self, limit: float) -> str:
        """How ``limit`` was found, for a stall's message."""
        if self.arrivals is None or limit >= self.limit:
            return 'limit %.3f s' % limit
        return 'adaptive limit %.3f s of at most %.3f s: %s' % (limit, self.limit, self.arrivals.describe())

    def connections(self) -> int:
        """How many publishers of the topic this probe is connected to now (0 once closed)."""
        sub = self._sub
        return sub.get_num_connections() if sub is not None else 0

    def close(self) -> None:
        """Stop watching and unsubscribe; safe to call more than once (a failure, then the unload)."""
        self.armed = False
        sub, self._sub = self._sub, None
        if sub is not None:
            sub.unregister()


class Watchdog:
    """One thread, a heap of deadlines; ``on_stall(probe, silence, limit)`` runs on that thread."""

    def __init__(self, on_stall: Callable[[TopicProbe, float, float], None]) -> None:
        self._on_stall = on_stall
        self._heap: List[tuple] = []
        self._seq = itertools.count()
        self._cond = threading.Condition()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name='sensor-watchdog', daemon=True)
        self._thread.start()

    def arm(self, probes: List[TopicProbe], grace: float = 0.0) -> None:
        """Start watching ``probes`` (with a limit > 0) from their last message.

        ``grace``: a probe that has seen no message yet (a sensor taken over after a restart of the
        manager, whose new subscription still connects) stalls only after ``max(grace, limit)``.
        """
        now = time.monotonic()
        with self._cond:
            for probe in probes:
                if probe.limit <= 0:
                    continue
                probe.armed = True
                if grace > 0:
                    probe.quiet_from = now + max(0.0, grace - probe.limit)
                limit = probe.current_limit()
                start = max(probe.last, now - limit, probe.quiet_from)
                heapq.heappush(self._heap, (self._next_look(probe, start + limit, now), next(self._seq), probe))
            self._cond.notify()

    @staticmethod
    def _next_look(probe: TopicProbe, due: float, now: float) -> float:
        """When to look at ``probe`` again: when it is due, or sooner if its limit may shrink meanwhile (an
        adaptive limit learns the rhythm after the arm; a deadline set from the catalogue's limit would
        otherwise hold a stall until then)."""
        if probe.arrivals is None:
            return due
        return min(due, now + ADAPTIVE_RECHECK)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stopped and not self._heap:
                    self._cond.wait()
                if self._stopped:
                    return
                deadline, _, probe = self._heap[0]
                now = time.monotonic()
                if deadline > now:
                    self._cond.wait(deadline - now)
                    continue
                heapq.heappop(self._heap)
                if not probe.armed:
                    continue
                since = max(probe.last, probe.quiet_from)
                limit = probe.current_limit()
                due = since + limit
                if due > now:
                    heapq.heappush(self._heap, (self._next_look(probe, due, now), next(self._seq), probe))
                    continue
                probe.armed = False
            try:
                self._on_stall(probe, now - since, limit)
            except Exception as err:     # a reporting error must not stop the watchdog
                rospy.logerr('sensor watchdog: stall callback for %s raised %r', probe.topic, err)

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify()
