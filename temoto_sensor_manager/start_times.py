"""How long each driver takes from its start to its first data, learnt as the stall limit is.

A candidate that stays silent after its start costs its first-data allowance before the
next one is tried. One allowance for every driver has to cover the slowest start on a loaded
machine (4 s), so a device that is silent from its start cost a fast driver twenty times
what it needs. Once an entry's driver has delivered data ``MIN_SAMPLES`` times, its
allowance is ``MARGIN`` times the longest of its last ``KEEP`` starts, never below
``FLOOR`` nor above the default. The samples are kept in the manager's journal with the
reliabilities, so they survive the manager and carry across loads.

The allowance is in seconds of the driver's own progress, not of the wall clock (:class:`StartDeadline`): the
time the driver's processes wait for a CPU meanwhile is added to it, so a start on a busy machine is not a false
failure (a D435 had "no data within 4.3 s after its driver started" beside other work), while a driver that runs
and sends nothing, or exits, still fails at its allowance, or at once.
"""
from typing import Callable, Dict, List, Optional

KEEP = 20           # starts remembered per entry
MIN_SAMPLES = 3     # starts seen before the learnt allowance replaces the default
MARGIN = 3.0        # x the longest start remembered (the stall limit's margin over the longest gap is 2)
FLOOR = 1.0         # seconds: never less, whatever the driver did lately


class StartTimes:
    def __init__(self, default: float) -> None:
        self.default = default
        self._seen: Dict[str, List[float]] = {}

    def add(self, name: str, seconds: float) -> None:
        seen = self._seen.setdefault(name, [])
        seen.append(round(seconds, 4))
        del seen[:-KEEP]

    def allowance(self, name: str) -> float:
        """Seconds the driver of entry ``name`` gets after its start to deliver its first data."""
        seen = self._seen.get(name, [])
        if len(seen) < MIN_SAMPLES:
            return self.default
        return min(self.default, max(FLOOR, MARGIN * max(seen)))

    def describe(self, name: str) -> str:
        seen = self._seen.get(name, [])
        if len(seen) < MIN_SAMPLES:
            return 'the default start-up allowance (%d of %d starts seen)' % (len(seen), MIN_SAMPLES)
        return 'a start-up allowance of %.1f s learnt from its last %d starts (longest %.2f s)' % (
            self.allowance(name), len(seen), max(seen))

    def samples(self) -> Dict[str, List[float]]:
        return {name: list(seen) for name, seen in self._seen.items()}

    def restore(self, kept: Optional[Dict[str, List[float]]]) -> None:
        for name, seen in (kept or {}).items():
            values = [float(s) for s in seen if isinstance(s, (int, float)) and 0 <= s < 3600]
            if values:
                self._seen[name] = values[-KEEP:]


class StartDeadline:
    """When a starting driver must have sent its first data: ``limit`` seconds after ``start``, plus the time its
    processes waited for a CPU since (``waited()``: their run-queue seconds, None once they are gone), never later
    than ``cap`` seconds after ``start``."""

    def __init__(self, start: float, limit: float, cap: float, waited: Callable[[], Optional[float]]) -> None:
        self.start, self.limit, self.cap = start, limit, max(cap, limit)
        self._waited = waited
        self._base = waited() or 0.0
        self.starved = 0.0                    # seconds of CPU waiting allowed for so far

    def remaining(self, now: float) -> float:
        total = self._waited()
        if total is not None:
            self.starved = max(self.starved, total - self._base)
        return min(self.start + self.cap, self.start + self.limit + self.starved) - now

    def describe(self) -> str:
        if self.starved < 0.05:
            return '%.1f s' % self.limit
        return '%.1f s, and %.1f s its driver waited for a CPU' % (self.limit, self.starved)
