"""Telling a silent sensor from a starved machine: how late the watchdog's own threads ran.

A stall is silence longer than a limit learnt from the stream's rhythm (``arrivals.py``). When both
cores are busy, a burst of work (a partition healing, every node waking at once) can hold back the
driver, the transport and this manager's own threads for longer than the rhythm ever showed, and a
healthy sensor was failed (0.20 s of silence against a limit of 0.19 s). The silence then says more
about the machine than about the sensor. Before a silence is called a stall, the watchdog asks three
things about the span it covers:

- how long the probe's receive thread waited for a CPU since it last read a message (its run-queue
  time from ``/proc/self/task/<tid>/schedstat``): a message sent on time may still sit unread;
- how much later than usual the watchdog's own timer woke (``watchdog.Lateness``): the same
  starvation, seen from the other thread; a wake-up more than 20 ms later than usual also gives the
  receive threads 50 ms to read what waited, once per silence, before the silence is judged;
- how much more the machine's tasks waited for a CPU than they usually do (``/proc/pressure/cpu``,
  "some", beyond its rate over the last ten seconds): a burst that held the driver back too.

The timer's lateness beyond the usual, plus the larger of the other two at most half the limit, is
added to the limit for that look. A steady load (two CPU hogs all along) adds almost nothing, since
each usual follows it and the adaptive limit has learnt the rhythm under it; a real stall during a
burst is still caught, late by that much at most.
"""
import collections
import threading
from typing import Deque, Optional, Tuple

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


class MachinePressure:
    """Readings of the machine's CPU pressure, and how much a span had beyond the usual."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._readings: Deque[Tuple[float, float]] = collections.deque()
        self._usual = None          # seconds of pressure per second, averaged over about USUAL_TAU_S
        self.available = pressure_total() is not None

    def sample(self, now: float) -> None:
        if not self.available:
            return
        with self._lock:
            if self._readings and now - self._readings[-1][0] < SAMPLE_EVERY:
                return
            total = pressure_total()
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
