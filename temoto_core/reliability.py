"""A moving-average reliability, as the original's ``common/reliability``.

It starts with every one of its samples equal to a prior, so one event moves
the mean by only ``1/window``; but with equal priors one failure is enough to
reorder candidates, which is what makes a failed device lose its rank.
Shared by the sensor and context managers.
"""
import threading
from collections import deque

DEFAULT_PRIOR = 0.8
DEFAULT_WINDOW = 100


class Reliability:
    """Mean of the last ``window`` samples in [0, 1]; success adds 1.0, failure 0.0."""

    def __init__(self, prior: float = DEFAULT_PRIOR, window: int = DEFAULT_WINDOW) -> None:
        if not 0.0 <= prior <= 1.0:
            raise ValueError('reliability prior must be in [0, 1], got %r' % (prior,))
        if window < 1:
            raise ValueError('reliability window must be >= 1, got %r' % (window,))
        self._lock = threading.Lock()
        self._samples = deque([float(prior)] * window, maxlen=window)
        self._sum = float(prior) * window

    def adjust(self, sample: float) -> float:
        """Replace the oldest sample with ``sample`` (clamped to [0, 1]); return the new mean."""
        sample = min(1.0, max(0.0, float(sample)))
        with self._lock:
            self._sum += sample - self._samples[0]
            self._samples.append(sample)
            return self._sum / len(self._samples)

    def success(self) -> float:
        return self.adjust(1.0)

    def failure(self) -> float:
        return self.adjust(0.0)

    def samples(self) -> list:
        """The window, oldest first: what :meth:`restore` takes back (a manager keeps it across a crash)."""
        with self._lock:
            return list(self._samples)

    def restore(self, samples: list) -> None:
        """Continue from ``samples`` (as :meth:`samples` gave them); a window of another size is refitted."""
        values = [min(1.0, max(0.0, float(x))) for x in samples][-self._samples.maxlen:]
        with self._lock:
            prior = list(self._samples)[:self._samples.maxlen - len(values)]
            self._samples.clear()
            self._samples.extend(prior + values)
            self._sum = sum(self._samples)

    @property
    def value(self) -> float:
        with self._lock:
            return self._sum / len(self._samples)

    def __repr__(self) -> str:
        return 'Reliability(%.3f)' % self.value
