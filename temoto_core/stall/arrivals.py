"""Stall detection from a stream's own rhythm: the silence limit follows the measured inter-arrival times.

One fixed limit per topic has to cover the worst gap the topic ever shows on a loaded machine, so it
reports every stall late: the simulated D435 needed 0.5 s at 30 Hz, fifteen periods. A stream's gaps
are mostly close to its mean, and the limit can follow them: ``mean + SPREAD_FACTOR x spread`` over
the last ``WINDOW`` gaps, the threshold of a phi-accrual detector (Hayashibara et al., 2004) with a
normal model, phi of about 9 for a factor of 6. Two guards keep it honest when the model is wrong:

- the limit is never below ``FLOOR_PERIODS`` nominal periods (a lost message is not a stall), nor below
  ``FLOOR_S`` (a loaded machine's scheduling gap is not a stall either: a 100 Hz hand source's learnt limit
  of 29 ms once called a 48 ms gap a stall and sent its action into a failover), nor below
  ``MAX_GAP_MARGIN`` times the longest gap of the last ``HISTORY_BUCKETS`` x ``BUCKET`` gaps,
  about a minute (a machine that was slow a minute ago may be slow again: gap tails are much heavier
  than a normal model says; with two CPU hogs, a 25 Hz scan whose gaps had a mean of 40 ms, a spread of
  13 ms and a longest gap of 129 ms in the last minute then showed a gap of 194 ms);
- it is never above the catalogue's limit (``stall_timeout``, or three periods), which is also the
  limit until ``WARMUP`` gaps have been seen, unless the device's rhythm was learnt in an earlier load
  (``seed``): a stall early in a load is then caught at the learnt limit, not at the catalogue's (the
  demo's Hokuyo was stalled within its learning time and caught after 12 periods).

The cost per message is a few float operations on the subscriber's thread; the limit itself is
computed only when the stall detector wakes.
"""
import collections
import math
from typing import Deque, Optional, Tuple

WINDOW = 300            # gaps of the mean and spread: 10 s at 30 Hz
WARMUP = 100            # gaps before the measured rhythm is trusted (3 s at 30 Hz)
SPREAD_FACTOR = 6.0     # limit = mean + SPREAD_FACTOR x spread
MIN_SPREAD = 0.1        # x mean: a perfectly regular stream still gets a margin
FLOOR_PERIODS = 2.5     # nominal (or measured) periods: the shortest limit
FLOOR_S = 0.08          # seconds: the shortest limit whatever the rate (above a loaded 2-core machine's 48 ms
                        # scheduling gaps; only sources faster than 31 Hz reach it)
MAX_GAP_MARGIN = 2.0    # x the longest recent gap: the limit stays above what the stream did lately (1.5 let
                        # two false stalls through in 10 min with two CPU hogs: bench_stall.py)
BUCKET = 100            # gaps per bucket of the longest-gap history
HISTORY_BUCKETS = 20    # buckets kept: the longest gap of the last 2000 (67 s at 30 Hz)


class ArrivalModel:
    """The last ``window`` inter-arrival times of one topic: their mean, spread and maximum."""

    def __init__(self, window: int = WINDOW) -> None:
        self.window = window
        self._gaps: Deque[float] = collections.deque()
        self._sum = 0.0
        self._sum_sq = 0.0
        self._added = 0
        self._longest_now = 0.0                        # the bucket being filled
        self._longest_past: Deque[float] = collections.deque(maxlen=HISTORY_BUCKETS - 1)
        self._prior: Optional[Tuple[float, float, float]] = None   # (mean, spread, longest) of an earlier load

    def seed(self, rhythm: Optional[Tuple[float, float, float]]) -> None:
        """The rhythm an earlier load of the same device learnt: the limit until this load has learnt its own."""
        if rhythm and len(rhythm) == 3 and all(isinstance(x, (int, float)) and 0 <= x < 60 for x in rhythm) \
                and rhythm[0] > 0:
            self._prior = (float(rhythm[0]), float(rhythm[1]), float(rhythm[2]))

    def rhythm(self) -> Optional[Tuple[float, float, float]]:
        """(mean, spread, longest) once learnt, to seed the device's next load; None before.

        The longest gap carried over is the median of the longest gap of each bucket of 100, what a load
        learns in its first 100 gaps, not the longest of the last minute: carrying that over made every
        reload start at twice the worst gap a minute of two CPU hogs had shown (the Hokuyo's stall caught
        after 280 ms instead of 107 ms, bench_stall.py)."""
        if len(self._gaps) < WARMUP:
            return None
        buckets = sorted(list(self._longest_past) + ([self._longest_now] if self._added % BUCKET else []))
        typical = buckets[len(buckets) // 2] if buckets else self.longest()
        return (round(self.mean(), 6), round(self.spread(), 6), round(typical, 6))

    def add(self, gap: float) -> None:
        gaps = self._gaps
        gaps.append(gap)
        self._sum += gap
        self._sum_sq += gap * gap
        if len(gaps) > self.window:
            old = gaps.popleft()
            self._sum -= old
            self._sum_sq -= old * old
        self._added += 1
        if gap > self._longest_now:
            self._longest_now = gap
        if self._added % BUCKET == 0:
            self._longest_past.append(self._longest_now)
            self._longest_now = 0.0
        if self._added % self.window == 0:    # running sums drift: start them again from the window
            self._sum = math.fsum(gaps)
            self._sum_sq = math.fsum(g * g for g in gaps)

    def mean(self) -> float:
        return self._sum / len(self._gaps) if self._gaps else 0.0

    def spread(self) -> float:
        """The standard deviation of the window's gaps."""
        n = len(self._gaps)
        if n < 2:
            return 0.0
        mean = self._sum / n
        return math.sqrt(max(0.0, self._sum_sq / n - mean * mean))

    def longest(self) -> float:
        """The longest gap of the history (about the last HISTORY_BUCKETS x BUCKET gaps)."""
        return max(max(self._longest_past, default=0.0), self._longest_now)

    def limit(self, cap: float, nominal_period: float = 0.0) -> float:
        """The silence that counts as a stall now: adaptive between the floor and ``cap`` (the cap itself
        while warming up). ``nominal_period``: 1 / the catalogue's rate (0: unknown; the measured mean
        then sets the floor)."""
        if len(self._gaps) >= WARMUP:
            mean, spread, longest = self.mean(), self.spread(), self.longest()
        elif self._prior is not None:
            mean, spread, prior_longest = self._prior
            longest = max(prior_longest, self.longest())
        else:
            return cap
        adaptive = mean + SPREAD_FACTOR * max(spread, MIN_SPREAD * mean)
        floor = max(FLOOR_S, FLOOR_PERIODS * (nominal_period or mean), MAX_GAP_MARGIN * longest)
        return min(cap, max(floor, adaptive))

    def describe(self) -> str:
        if len(self._gaps) < WARMUP and self._prior is not None:
            return 'mean gap %.3f s, spread %.3f s, longest %.3f s learnt in an earlier load (%d gaps in this one)' % (
                self._prior + (len(self._gaps),))
        return 'mean gap %.3f s, spread %.3f s over the last %d gaps, longest lately %.3f s' % (
            self.mean(), self.spread(), len(self._gaps), self.longest())
