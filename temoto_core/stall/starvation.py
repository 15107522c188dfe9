"""Telling a silent sensor from a starved machine: how late the stall detector's own threads ran.

A stall is silence longer than a limit learnt from the stream's rhythm (``arrivals.py``). When both
cores are busy, a burst of work (a partition healing, every node waking at once) can hold back the
driver, the transport and this manager's own threads for longer than the rhythm ever showed, and a
healthy sensor was failed (0.20 s of silence against a limit of 0.19 s). The silence then says more
about the machine than about the sensor. Before a silence is called a stall, the stall detector asks three
things about the span it covers:

- how long the probe's receive thread waited for a CPU since it last read a message (its run-queue
  time from ``/proc/self/task/<tid>/schedstat``): a message sent on time may still sit unread;
- how much later than usual the stall detector's own timer woke (``detector.Lateness``): the same
  starvation, seen from the other thread; a wake-up more than 20 ms later than usual also gives the
  receive threads 50 ms to read what waited, once per silence, before the silence is judged;
- how much more the machine's tasks waited for a CPU than they usually do (``/proc/pressure/cpu``,
  "some", beyond its rate over the last ten seconds): a burst that held the driver back too;
- how much more the publishing driver's own threads waited for a CPU than they usually do, when the
  driver runs on this host (``/proc/<pid>/task/*/schedstat``, beyond its rate over the last ten
  seconds). The machine's pressure says little once two CPU hogs keep some task waiting all the time
  (it saturates); the driver's own wait still rises in a burst. A SICK scanner held 30 s beside two
  hogs, with the link to the station cut and healed every 10 s, was called stalled after 0.375 s
  against a limit of 0.300 s plus 0.074 s: its driver had been held back.

The timer's lateness beyond the usual, plus the driver's and the receive thread's waits (a message
waits for the one, then for the other: they add up) or the machine's excess if that is larger, at most
half the limit, is added to the limit for that look. A driver that hangs or stops publishing runs less, not more, so a
real stall is not mistaken for a starved driver. A steady load (two CPU hogs all along) adds almost nothing, since
each usual follows it and the adaptive limit has learnt the rhythm under it; a real stall during a
burst is still caught, late by that much at most.
"""
import collections
import os
import threading
from typing import Callable, Deque, Optional, Tuple

PRESSURE = '/proc/pressure/cpu'
SAMPLE_EVERY = 0.05       # seconds between two readings of the machine's pressure
KEEP_S = 5.0              # seconds of readings kept (a silence longer than this is a stall anyway)
USUAL_TAU_S = 10.0        # seconds: the time constant of the usual pressure rate (a burst is far shorter)


def thread_wait(tid: int) -> Optional[float]:
    """Seconds thread ``tid`` of this process has spent waiting on a run queue, or None if unknown."""
    try:
        with open('/proc/self/task/%d/schedstat' % tid, 'rb') as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return None


def pressure_total() -> Optional[float]:
    """Seconds, since boot, during which some runnable task of the machine waited for a CPU (PSI)."""
    try:
        with open(PRESSURE, 'rb') as f:
            for line in f:
                if line.startswith(b'some'):
                    return int(line.rsplit(b'total=', 1)[1]) / 1e6
    except (OSError, ValueError, IndexError):
        pass
    return None


def process_wait(pid: int) -> Optional[float]:
    """Seconds the threads of process ``pid`` (on this host) have spent waiting on a run queue, or None if
    it is gone. Threads that ended take their share with them: a span's excess is then undercounted."""
    total = 0.0
    try:
        tids = os.listdir('/proc/%d/task' % pid)
    except OSError:
        return None
    for tid in tids:
        try:
            with open('/proc/%d/task/%s/schedstat' % (pid, tid), 'rb') as f:
                total += int(f.read().split()[1]) / 1e9
        except (OSError, ValueError, IndexError):
            continue                      # a thread that ended between the listing and the read
    return total


def tree_wait(pid: int) -> Optional[float]:
    """:func:`process_wait` of ``pid`` and of every process below it (a ``roslaunch`` and the nodes it started),
    or None if ``pid`` is gone."""
    total = process_wait(pid)
    if total is None:
        return None
    try:
        tids = os.listdir('/proc/%d/task' % pid)
    except OSError:
        return total
    for tid in tids:
        try:
            with open('/proc/%d/task/%s/children' % (pid, tid)) as f:
                children = [int(c) for c in f.read().split()]
        except (OSError, ValueError):
            continue
        for child in children:
            total += tree_wait(child) or 0.0
    return total


class WaitMeter:
    """Readings of a total of CPU waiting (the machine's, or a process's), and how much a span had beyond
    the usual rate. ``sample`` is called often (every look of the stall detector); it reads at most every
    ``SAMPLE_EVERY`` seconds."""

    def __init__(self, read_total: Callable[[], Optional[float]]) -> None:
        self._read_total = read_total
        self._lock = threading.Lock()
        self._readings: Deque[Tuple[float, float]] = collections.deque()
        self._usual = None          # seconds of waiting per second, averaged over about USUAL_TAU_S
        self.available = read_total() is not None

    def sample(self, now: float) -> None:
        if not self.available:
            return
        with self._lock:
            if self._readings and now - self._readings[-1][0] < SAMPLE_EVERY:
                return
            total = self._read_total()
            if total is None:
                return
            if self._readings:
                t0, p0 = self._readings[-1]
                rate = (total - p0) / max(now - t0, 1e-3)
                weight = min(1.0, (now - t0) / USUAL_TAU_S)
                self._usual = rate if self._usual is None else self._usual + weight * (rate - self._usual)
            self._readings.append((now, total))
            while self._readings and now - self._readings[0][0] > KEEP_S:
                self._readings.popleft()

    def excess(self, since: float, now: float) -> float:
        """Seconds of CPU waiting in [since, now] beyond the usual rate (0 when unknown)."""
        with self._lock:
            if self._usual is None or not self._readings:
                return 0.0
            start = None
            for t, total in self._readings:
                if t <= since:
                    start = (t, total)
                else:
                    break
            if start is None:
                start = self._readings[0]
            end = self._readings[-1]
            usual = self._usual
        span = end[0] - start[0]
        return max(0.0, (end[1] - start[1]) - usual * span)


def machine_pressure() -> WaitMeter:
    """The machine's CPU pressure (PSI "some"): unavailable on kernels without it."""
    return WaitMeter(pressure_total)


def process_meter(pid: int) -> WaitMeter:
    """The CPU waiting of process ``pid``'s threads."""
    return WaitMeter(lambda: process_wait(pid))
