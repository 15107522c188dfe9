"""Stall detector: first-message detection and stall detection for held sensors.

A driver whose cable is pulled may stay alive and publish nothing; the ER
Manager cannot see that. Each watched topic records the arrival time of its
last message, and the gap since the one before (``arrivals.py``: the limit
follows the topic's own rhythm, within the catalogue's). One
thread keeps a heap of deadlines and sleeps until the earliest: if a message
arrived meanwhile the entry is pushed again to ``last + limit``, otherwise the
topic has been silent for its whole limit and the stall callback runs. So the
thread wakes about once per limit per topic, and a stall is reported at most a
scheduling delay after the limit, never a poll period later.

A silence is called a stall only once it is longer than the limit plus the time
the machine held this manager's own threads, or the driver's, back meanwhile
(``starvation.py``): a starved machine is not a silent sensor.
"""
import collections
import heapq
import itertools
import threading
import time
from typing import Callable, List, Optional

import rospy

from temoto_core.rospy_internals import sender_of
from temoto_core.stall.arrivals import ArrivalModel
from temoto_core.stall.starvation import WaitMeter, machine_pressure, process_meter, thread_wait


# seconds: the longest an adaptive probe goes unchecked (its limit may have shrunk since the last look)
ADAPTIVE_RECHECK = 0.1
LATE_WAKE = 0.02        # seconds beyond the usual lateness: a wake-up this late says this process was held back
CATCH_UP = 0.05         # seconds the receive threads get to read what waited after such a wake-up


class TopicProbe:
    """An ``AnyMsg`` subscription that remembers when its topic last carried a message, and its rhythm."""

    def __init__(self, topic: str, limit: float, on_first: Optional[Callable[[], None]] = None,
                 rate: float = 0.0, adaptive: bool = True, key: str = '') -> None:
        """``limit``: the catalogue's silence limit (0: not watched); with ``adaptive``, the most the
        limit measured from the topic's own rhythm may be (``arrivals.py``). ``rate``: nominal Hz (0:
        unknown)."""
        self.topic = topic
        self.key = key                       # the catalogue's topic type (camera_data, ...): whose rhythm this is
        self.limit = limit                   # seconds of silence that count as a stall at most; 0: not watched
        self.nominal_period = 1.0 / rate if rate > 0 else 0.0
        self.arrivals = ArrivalModel() if adaptive else None
        self.last = 0.0                      # time.monotonic() of the last message
        self.count = 0
        self.max_gap = 0.0                   # longest time between two messages seen (what a limit must exceed)
        self.first = threading.Event()
        self.armed = False
        self.quiet_from = 0.0                # silence counts from max(last, quiet_from): see StallDetector.arm
        self.owner = None                    # set by the stall detector user (what stalled)
        self.reader_tid = 0                  # the thread that reads this topic's messages
        self.reader_wait: Optional[float] = None   # its run-queue time at the last message (starvation.py)
        self.silence_from = -1.0             # the silence that the two below belong to
        self.late = 0.0                      # how much later than usual the stall detector woke at most, in it
        self.caught_up = False               # whether it was given its one catch-up after a late wake-up
        self.starved = 0.0                   # the starvation allowed for at the last look (for the message)
        self.starved_parts = (0.0, 0.0, 0.0, 0.0)   # its parts: timer lateness, driver, receive thread, machine
        self.publisher = ''                  # the node that sent the first message (its connection header)
        self.publisher_pid = 0               # its process, when it runs on this host (0: not known)
        self.publisher_wait: Optional[WaitMeter] = None   # that process's threads' CPU waiting
        self._on_first = on_first
        self._sub = rospy.Subscriber(topic, rospy.AnyMsg, self._on_msg, queue_size=1, tcp_nodelay=True)

    def _on_msg(self, _msg) -> None:
        now = time.monotonic()
        if not self.reader_tid:
            self.reader_tid = threading.get_native_id()
        if self.armed:
            self.reader_wait = thread_wait(self.reader_tid)
        if self.count:
            gap = now - self.last
            if gap > self.max_gap:
                self.max_gap = gap
            if self.arrivals is not None and self.armed:    # a driver's start-up is not its rhythm
                self.arrivals.add(gap)
        self.last = now
        self.count += 1
        if not self.first.is_set():
            self.publisher = sender_of(_msg)
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
        starved = (', plus %.3f s the machine held this manager or the driver back (%s)' % (
            self.starved, 'its timer %.3f s late; beyond their usual waits: the driver %.3f s, the receive thread '
            '%.3f s, the machine %.3f s' % self.starved_parts) if self.starved > 0.0005 else '')
        if self.arrivals is None or limit >= self.limit:
            return 'limit %.3f s%s' % (limit, starved)
        return 'adaptive limit %.3f s of at most %.3f s%s: %s' % (limit, self.limit, starved,
                                                                  self.arrivals.describe())

    def measure_publisher(self, pid: int) -> None:
        """Count the waiting of the publishing driver's process ``pid`` (on this host) as starvation."""
        self.publisher_pid = pid
        self.publisher_wait = process_meter(pid)

    def publisher_starved(self, since: float, now: float) -> float:
        """Seconds the publishing driver's threads waited for a CPU in [since, now] beyond their usual."""
        meter = self.publisher_wait
        return meter.excess(since, now) if meter is not None else 0.0

    def reader_starved(self) -> float:
        """Seconds the receive thread waited for a CPU since it read the last message (0 if unknown)."""
        before = self.reader_wait
        if before is None or not self.reader_tid:
            return 0.0
        now = thread_wait(self.reader_tid)
        return max(0.0, now - before) if now is not None else 0.0

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


class Lateness:
    """How late the stall detector's thread usually wakes: on a loaded machine a few tens of milliseconds is the
    norm, and only what goes beyond it says that this process was held back."""

    def __init__(self, keep: int = 200) -> None:
        self._recent: collections.deque = collections.deque(maxlen=keep)

    def beyond_usual(self, late: float) -> float:
        """Seconds ``late`` (this wake-up's) goes beyond the 90th percentile of the last wake-ups; recorded."""
        late = max(0.0, late)
        recent = self._recent
        usual = sorted(recent)[int(0.9 * (len(recent) - 1))] if len(recent) >= 20 else 0.0
        recent.append(late)
        return max(0.0, late - usual)


class StallDetector:
    """One thread, a heap of deadlines; ``on_stall(probe, silence, limit)`` runs on that thread."""

    def __init__(self, on_stall: Callable[[TopicProbe, float, float], None]) -> None:
        self._on_stall = on_stall
        self._heap: List[tuple] = []
        self._seq = itertools.count()
        self._cond = threading.Condition()
        self._stopped = False
        self.pressure = machine_pressure()
        self.lateness = Lateness()
        self._thread = threading.Thread(target=self._run, name='stall-detector', daemon=True)
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
                self.pressure.sample(now)
                if probe.publisher_wait is not None:
                    probe.publisher_wait.sample(now)
                since = max(probe.last, probe.quiet_from)
                if probe.silence_from != since:
                    probe.silence_from, probe.late, probe.caught_up = since, 0.0, False
                late = self.lateness.beyond_usual(now - deadline)
                probe.late = max(probe.late, late)
                limit = probe.current_limit()
                due = since + limit
                if due <= now and late > LATE_WAKE and not probe.caught_up:
                    # this thread ran late, and so may the receive thread, with messages waiting unread:
                    # it gets a moment to catch up before the silence is judged (once per silence)
                    probe.caught_up = True
                    due = now + CATCH_UP
                elif due <= now:
                    # long enough, unless the machine held this manager or the driver back meanwhile
                    # (starvation.py): by how late this thread woke beyond the usual, and by what the driver
                    # and the receive thread waited beyond the usual (one after the other on a message's way:
                    # their waits add up), or the machine's excess if larger, at most half the limit (a
                    # real stall comes late by that much at the most)
                    driver, reader = probe.publisher_starved(since, now), probe.reader_starved()
                    machine = self.pressure.excess(since, now)
                    probe.starved = probe.late + min(0.5 * limit, max(driver + reader, machine))
                    probe.starved_parts = (probe.late, driver, reader, machine)
                    due += probe.starved
                if due > now:
                    heapq.heappush(self._heap, (self._next_look(probe, due, now), next(self._seq), probe))
                    continue
                probe.armed = False
            try:
                self._on_stall(probe, now - since, limit)
            except Exception as err:     # a reporting error must not stop the stall detector
                rospy.logerr('stall detector: stall callback for %s raised %r', probe.topic, err)

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify()
