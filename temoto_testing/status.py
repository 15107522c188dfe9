"""Timing a failure: when did the first FAILED status reach a consumer."""
import threading
import time
from typing import Optional


class FirstFailure:
    """A status callback that notes when the first FAILED arrived (``time.monotonic()``)."""

    def __init__(self) -> None:
        self.stamp: Optional[float] = None
        self._got = threading.Event()

    def __call__(self, event) -> None:
        if event.code == 1 and not self._got.is_set():      # ResourceStatus.FAILED
            self.stamp = time.monotonic()
            self._got.set()

    def wait(self, timeout: float, what: str = 'FAILED') -> float:
        """The stamp; raises TimeoutError naming ``what`` when none came within ``timeout`` s."""
        if not self._got.wait(timeout):
            raise TimeoutError('no %s within %.0f s' % (what, timeout))
        return self.stamp
