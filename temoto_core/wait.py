"""Waiting on a condition, never on a fixed sleep."""
import time
from typing import Callable, TypeVar

T = TypeVar('T')


def wait_for(predicate: Callable[[], T], timeout: float, what: str, interval: float = 0.01) -> T:
    """Poll ``predicate`` until it returns a truthy value, and return that value.

    Raises ``TimeoutError`` naming ``what`` after ``timeout`` seconds. The poll
    interval grows from ``interval`` to at most 0.1 s, so short waits stay fast
    and long ones stay cheap; the loop is bounded by the deadline.
    """
    deadline = time.monotonic() + timeout
    delay = interval
    while True:
        value = predicate()
        if value:
            return value
        now = time.monotonic()
        if now >= deadline:
            raise TimeoutError('timed out after %.1f s waiting for %s' % (timeout, what))
        time.sleep(min(delay, deadline - now))
        delay = min(delay * 1.5, 0.1)
